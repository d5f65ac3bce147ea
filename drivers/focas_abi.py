"""ctypes view of the FOCAS library subset compd uses (libfwlib32.so).

ABI facts (docs/protocols.md §9): plain cdecl; every FOCAS ``long`` is 32 bits, also
in the 64-bit Linux library, so it is ``c_int32`` here, never ``c_long``;
structs are packed to 4 (``_pack_ = 4``). `tests/drivers/test_focas.py`
compares these layouts with what a C compiler makes of the same structs.
"""

from __future__ import annotations

import ctypes
from ctypes import (
    POINTER,
    Structure,
    Union,
    c_char,
    c_char_p,
    c_double,
    c_float,
    c_int16,
    c_int32,
    c_uint16,
)
from typing import Any

from drivers.errors import BadAddress, ConnectionLost, DriverError, WriteRejected

FLONG = c_int32  # a FOCAS "long"
MAX_AXIS = 32
MAX_SPINDLE = 8
#: bytes before the data part of IODBPMC (type_a, type_d, datano_s, datano_e)
PMC_HEADER_BYTES = 8

# ---- return codes --------------------------------------------------------
EW_OK, EW_FUNC, EW_LENGTH, EW_NUMBER, EW_ATTRIB, EW_DATA = 0, 1, 2, 3, 4, 5
EW_NOOPT, EW_PROT, EW_OVRFLOW, EW_PARAM, EW_BUFFER, EW_PATH = 6, 7, 8, 9, 10, 11
EW_MODE, EW_REJECT, EW_ALARM, EW_STOP, EW_PASSWD = 12, 13, 15, 16, 17
EW_BUSY, EW_RESET, EW_HANDLE, EW_SOCKET, EW_PROTOCOL = -1, -2, -8, -16, -17

EW_NAMES: dict[int, str] = {
    0: "EW_OK", 1: "EW_FUNC", 2: "EW_LENGTH", 3: "EW_NUMBER", 4: "EW_ATTRIB", 5: "EW_DATA",
    6: "EW_NOOPT", 7: "EW_PROT", 8: "EW_OVRFLOW", 9: "EW_PARAM", 10: "EW_BUFFER",
    11: "EW_PATH", 12: "EW_MODE", 13: "EW_REJECT", 15: "EW_ALARM", 16: "EW_STOP",
    17: "EW_PASSWD", -1: "EW_BUSY", -2: "EW_RESET", -8: "EW_HANDLE", -16: "EW_SOCKET",
    -17: "EW_PROTOCOL",
}
#: the link (or the handle) is gone: drop the handle and reconnect
LINK_CODES = frozenset({EW_SOCKET, EW_HANDLE, EW_PROTOCOL})
#: the request names something the controller does not have
ADDRESS_CODES = frozenset({EW_NUMBER, EW_ATTRIB, EW_LENGTH, EW_NOOPT})
#: a refusal that may pass (busy, reset in progress, wrong mode, alarm)
TRANSIENT_CODES = frozenset({EW_BUSY, EW_RESET, EW_MODE, EW_ALARM, EW_STOP})


class IODBPMC(Structure):
    class _U(Union):
        _pack_ = 4
        _fields_ = [("cdata", c_char * 5), ("idata", c_int16 * 5), ("ldata", FLONG * 5),
                    ("fdata", c_float * 5), ("dbdata", c_double * 5)]

    _pack_ = 4
    _fields_ = [("type_a", c_int16), ("type_d", c_int16), ("datano_s", c_uint16),
                ("datano_e", c_uint16), ("u", _U)]


class ODBSPN(Structure):
    _pack_ = 4
    _fields_ = [("datano", c_int16), ("type", c_int16), ("data", c_int16 * MAX_SPINDLE)]


class REALDGN(Structure):
    _pack_ = 4
    _fields_ = [("dgn_val", FLONG), ("dec_val", FLONG)]


class ODBDGN(Structure):
    class _U(Union):
        _pack_ = 4
        _fields_ = [("cdata", c_char), ("idata", c_int16), ("ldata", FLONG),
                    ("rdata", REALDGN), ("cdatas", c_char * MAX_AXIS),
                    ("idatas", c_int16 * MAX_AXIS), ("ldatas", FLONG * MAX_AXIS),
                    ("rdatas", REALDGN * MAX_AXIS)]

    _pack_ = 4
    _fields_ = [("datano", c_int16), ("type", c_int16), ("u", _U)]


def pmc_buffer(data_bytes: int) -> ctypes.Array[ctypes.c_uint8]:
    """A buffer for pmc_rdpmcrng/pmc_wrpmcrng: the 8-byte header plus
    `data_bytes` of data, never smaller than IODBPMC itself."""
    return (ctypes.c_uint8 * max(ctypes.sizeof(IODBPMC), PMC_HEADER_BYTES + data_bytes))()


_PROTOTYPES: dict[str, tuple[list[Any], Any]] = {
    "cnc_startupprocess": ([FLONG, c_char_p], c_int16),
    "cnc_exitprocess": ([], c_int16),
    "cnc_allclibhndl3": ([c_char_p, c_uint16, FLONG, POINTER(c_uint16)], c_int16),
    "cnc_freelibhndl": ([c_uint16], c_int16),
    "pmc_rdpmcrng": ([c_uint16, c_int16, c_int16, c_uint16, c_uint16, c_uint16,
                      ctypes.c_void_p], c_int16),
    "pmc_wrpmcrng": ([c_uint16, c_uint16, ctypes.c_void_p], c_int16),
    "cnc_rdspload": ([c_uint16, c_int16, POINTER(ODBSPN)], c_int16),
    "cnc_diagnoss": ([c_uint16, c_int16, c_int16, c_int16, POINTER(ODBDGN)], c_int16),
}


def load(path: str) -> ctypes.CDLL:
    """Load the library and declare argtypes/restype of every function used."""
    lib = ctypes.CDLL(path)
    for name, (argtypes, restype) in _PROTOTYPES.items():
        fn = getattr(lib, name)
        fn.argtypes = argtypes
        fn.restype = restype
    return lib


def ew_name(code: int) -> str:
    return EW_NAMES.get(code, f"EW_{code}")


def error_for(code: int, what: str, *, channel: str | None = None,
              address: str | None = None, writing: bool = False) -> DriverError:
    """The driver error for a non-zero FOCAS return code."""
    msg = f"{what} returned {ew_name(code)} ({code})"
    if code in LINK_CODES:
        return ConnectionLost(msg, channel=channel, address=address)
    if code in ADDRESS_CODES:
        return BadAddress(msg, channel=channel, address=address)
    if writing:
        return WriteRejected(msg, channel=channel, address=address,
                             permanent=code not in TRANSIENT_CODES)
    return DriverError(msg, channel=channel, address=address)
