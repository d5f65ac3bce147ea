"""Compile the stand-in FOCAS library (`fwlib_standin.c`) with the system C
compiler, cached by the hash of its source."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

SOURCE = Path(__file__).with_name("fwlib_standin.c")


def default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "compd"


def _compile(out: Path, *flags: str) -> Path:
    cc = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        raise RuntimeError("no C compiler found (install gcc) to build the FOCAS stand-in")
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=out.name, suffix=".tmp")
    os.close(fd)
    try:
        subprocess.run([cc, "-O2", "-Wall", *flags, "-o", tmp, str(SOURCE)], check=True,
                       capture_output=True, text=True, timeout=120)
        os.replace(tmp, out)  # atomic: concurrent builders never see a half-written file
    except subprocess.CalledProcessError as exc:
        raise RuntimeError(f"building {SOURCE.name} failed:\n{exc.stderr}") from exc
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out


def _digest() -> str:
    return hashlib.sha256(SOURCE.read_bytes()).hexdigest()[:16]


def build_standin(out_dir: Path | None = None) -> Path:
    """The absolute path of the compiled stand-in ``libfwlib32`` (built once)."""
    target = (out_dir or default_cache_dir()).resolve() / f"libfwlib32-standin-{_digest()}.so"
    if target.exists():
        return target
    return _compile(target, "-shared", "-fPIC")


def build_abi_probe(out_dir: Path) -> Path:
    """A program printing the C sizes/offsets of the FOCAS structs."""
    return _compile(out_dir.resolve() / f"fwlib-abi-probe-{_digest()}", "-DCOMPD_ABI_PROBE")
