"""What the daemon does to the kernel, in one short process, for the syscall
audit in test_systemd_unit.py (run under strace as an unprivileged user, as
DynamicUser= runs the service).

It exercises every kind of system call `compd run` makes: the interpreter and
numpy start-up, a model stepping, the state lock (flock), an atomic checkpoint
(fsync, rename, directory fsync), SQLite in WAL mode (the recorder), asyncio
TCP on loopback through the real Modbus driver and simulated controller,
worker threads (the FOCAS I/O thread) and ctypes calls into C libraries
(libc, and the stand-in FOCAS library when COMPD_WORKLOAD_FWLIB names it).

Usage: python -m tests.deploy.syscall_workload STATE_DIR
"""

from __future__ import annotations

import asyncio
import ctypes
import os
import sqlite3
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


def _model_and_state(state_dir: Path) -> None:
    from compd.infiles import load_model
    from compd.runtime.checkpoint import load_checkpoint, save_checkpoint
    from compd.runtime.statelock import StateLock

    model = load_model("sp2")
    offset_um = 0.0
    for k in range(50):
        offset_um = model.step({name: 20.0 + 0.01 * k for name in model.channels})
    with StateLock(state_dir):
        path = state_dir / "checkpoint.json"
        save_checkpoint(path, {"offset_um": float(offset_um), "sequence": 50})
        if load_checkpoint(path) is None:
            raise RuntimeError("checkpoint vanished")


def _sqlite_wal(state_dir: Path) -> None:
    db = sqlite3.connect(state_dir / "record.sqlite")
    db.execute("PRAGMA journal_mode=WAL")
    db.execute("PRAGMA synchronous=NORMAL")
    db.execute("CREATE TABLE IF NOT EXISTS samples (seq INTEGER PRIMARY KEY, offset_um REAL)")
    for k in range(30):
        db.execute("INSERT INTO samples VALUES (?, ?)", (k, 0.1 * k))
        if k % 10 == 9:
            db.commit()
    db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    db.close()


async def _loopback_modbus() -> None:
    from drivers.modbus import ModbusDriver
    from drivers.sim.modbus_server import ModbusSimController

    sim = ModbusSimController()
    await sim.start()
    try:
        driver = ModbusDriver(sim.endpoint, sim.channels, sim.outputs_map, timeout_s=0.5)
        await driver.connect()
        try:
            names = sorted(sim.channels)
            for k in range(5):
                await driver.read(names)
                await driver.write({next(iter(sim.outputs_map)): 0.5 * k})
        finally:
            await driver.close()
    finally:
        await sim.stop()


def _threads_and_ctypes() -> None:
    # By soname: ctypes.util.find_library would fork ldconfig, which compd never does.
    libc = ctypes.CDLL("libc.so.6")
    fwlib = os.environ.get("COMPD_WORKLOAD_FWLIB")
    if fwlib:  # the stand-in FOCAS library, loaded and called as drivers/focas.py does
        lib = ctypes.CDLL(fwlib)
        lib.cnc_startupprocess.restype = ctypes.c_short
        lib.cnc_startupprocess.argtypes = [ctypes.c_int32, ctypes.c_char_p]
        if lib.cnc_startupprocess(0, None) != 0 or lib.cnc_exitprocess() != 0:
            raise RuntimeError("FOCAS stand-in refused start-up")
    with ThreadPoolExecutor(max_workers=2) as pool:
        pids = list(pool.map(lambda _: libc.getpid(), range(4)))
    if len(set(pids)) != 1:
        raise RuntimeError("threads saw different pids")
    done = threading.Event()
    threading.Timer(0.01, done.set).start()
    done.wait(5.0)


def main(argv: list[str]) -> int:
    state_dir = Path(argv[1])
    _model_and_state(state_dir)
    _sqlite_wal(state_dir)
    asyncio.run(_loopback_modbus())
    _threads_and_ctypes()
    print("workload ok")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
