"""Project-wide test rules: warnings are errors (pyproject), an async test
that leaves asyncio tasks behind fails, and bytecode is compiled once a run.
And `listener`, a socket on 127.0.0.1 that listens and must never see a
connection (the endpoint of configs that must be refused before anything
connects), and `rec`, a simulated Modbus controller on 127.0.0.1 that records
every offset the daemon writes (`tests.faults.daemon_run.RecordingSim`)."""

from __future__ import annotations

import asyncio
import compileall
import functools
import inspect
import os
import re
import shutil
import socket
import sys
from collections.abc import AsyncIterator, Callable, Coroutine, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import settings

if TYPE_CHECKING:
    from tests.faults.daemon_run import RecordingSim

# Property tests search the same examples on every run (a fixed seed per test):
# a new counterexample is found when a test or its code changes, not at random
# in somebody else's CI run. HYPOTHESIS_PROFILE=explore searches afresh.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


#: the folders whose bytecode a run that writes none leaves as it found them
_OWN = ("compd", "drivers", "models", "tests", "benchmarks", "deploy")


def _caches(root: Path) -> set[Path]:
    found: set[Path] = set()
    for top in _OWN:
        for folder, subfolders, _ in os.walk(root / top):
            if "__pycache__" in subfolders:
                found.add(Path(folder, "__pycache__"))
            # node's packages (tests/interop) hold no Python
            subfolders[:] = [d for d in subfolders if d not in ("__pycache__", "node_modules")]
    return found


def pytest_configure(config: pytest.Config) -> None:
    """With PYTHONDONTWRITEBYTECODE set, every process of the run would compile
    every module of the project it imports again: each xdist worker rewrites
    and compiles every test module (about 7 of the 11 CPU-s of a collection),
    each `compd` process a test starts its 150 modules (about 0.1 CPU-s of its
    0.4). The run writes bytecode as CI's default does, beside the sources, and
    removes at the end the ``__pycache__`` folders it made: the tree is left as
    the setting asks, and each module is compiled once a run. (A cache prefix
    would not do: Python then ignores the bytecode installed with numpy,
    pydantic and the standard library, and compiles those again.)"""
    if not sys.dont_write_bytecode:
        return
    root = Path(__file__).resolve().parents[1]
    before = _caches(root)
    setting = os.environ.get("PYTHONDONTWRITEBYTECODE")

    def restore() -> None:
        if setting is not None:
            os.environ["PYTHONDONTWRITEBYTECODE"] = setting
        sys.dont_write_bytecode = True
        for made in _caches(root) - before:
            shutil.rmtree(made, ignore_errors=True)

    config.add_cleanup(restore)
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    sys.dont_write_bytecode = False


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_setupnodes(config: pytest.Config) -> None:
    """Before xdist's workers start, compile the project's bytecode once here.

    Each worker imports every test module and the project's modules at its
    collection, all at the same moment: with no bytecode on disk (a fresh clone,
    or any run under PYTHONDONTWRITEBYTECODE, whose folders `pytest_configure`
    removes at the end) every worker rewrote the asserts of all 250 test modules
    and compiled the rest itself, none finding what another was still writing:
    about 7 CPU-s of a worker's 11-second collection, four times a run. Written
    here once, before the workers exist, each of them reads it."""
    if not sys.dont_write_bytecode:
        _warm_bytecode(config, Path(__file__).resolve().parents[1])


#: test files and conftests: compiled by pytest's assert rewriting, not plainly
_REWRITTEN = re.compile(r"(^|/)(test_[^/]*|conftest)\.py$")


def _warm_bytecode(config: pytest.Config, root: Path) -> None:
    for top in ("compd", "drivers", "models", "tests"):
        compileall.compile_dir(root / top, quiet=2, rx=_REWRITTEN)
    # pytest's own cache of rewritten test modules, written as its import hook
    # writes it (the same file name, the same checks); private names, so a
    # pytest that moved them only loses the head start
    try:
        from _pytest.assertion import rewrite

        state = config.stash[rewrite.assertstate_key]
    except (ImportError, AttributeError, KeyError):
        return
    if not any(isinstance(h, rewrite.AssertionRewritingHook) for h in sys.meta_path):
        return  # --assert=plain: nothing is rewritten
    for fn in sorted((root / "tests").rglob("*.py")):
        if not _REWRITTEN.search(fn.as_posix()) or "node_modules" in fn.parts:
            continue
        cache_dir = rewrite.get_cache_dir(fn)
        if not rewrite.try_makedirs(cache_dir):
            return
        pyc = cache_dir / (fn.name[:-3] + rewrite.PYC_TAIL)
        if rewrite._read_pyc(fn, pyc, state.trace) is None:
            source_hash, co = rewrite._rewrite_test(fn, config)
            rewrite._write_pyc(state, co, source_hash, pyc)


def _guard(fn: Callable[..., Coroutine[Any, Any, Any]]) -> Callable[..., Coroutine[Any, Any, Any]]:
    @functools.wraps(fn)
    async def wrapper(*args: Any, **kwargs: Any) -> Any:
        before = asyncio.all_tasks()
        result = await fn(*args, **kwargs)
        for _ in range(20):  # let cancelled tasks finish unwinding
            leaked = asyncio.all_tasks() - before - {asyncio.current_task()}
            if not leaked:
                return result
            await asyncio.sleep(0.01)
        names = sorted(t.get_name() + ":" + repr(t.get_coro()) for t in leaked)
        pytest.fail(f"test left {len(leaked)} asyncio task(s) running: {names}")
    return wrapper


#: the files that hold a worker longest (measured, seconds in an idle run on 2
#: cores), sent to the workers first: xdist hands files out in collection order,
#: and one of these started last kept a worker busy after the others had ended
#: (about 20 s of a 190 s run). Mostly waits (LinuxCNC, real processes and
#: servers), which the other workers fill with CPU work. The LinuxCNC files share
#: one machine-wide lock: only one of them is here.
LONGEST_FIRST = (
    "tests/compd/runtime/test_axes_position_linuxcnc.py",  # 63
    "tests/compd/runtime/test_e2e_protocols.py",  # 30
    "tests/faults/test_slow_controller.py",  # 23
    "tests/compd/offline/test_adaptation_offline.py",  # 19
    "tests/compd/offline/test_report.py",  # 17
    "tests/compd/offline/test_shop_calibration.py",  # 17
    "tests/compd/runtime/test_e2e_adaptation.py",  # 16
    "tests/compd/offline/test_adaptation_real_record.py",  # 15
    "tests/compd/offline/test_cmd_fit_replay.py",  # 14
    "tests/faults/test_kill9.py",  # 11
    "tests/faults/test_health_while_held.py",  # 11
)


def _send_order(item: pytest.Item) -> int:
    path = item.nodeid.split("::", 1)[0]
    try:
        return LONGEST_FIRST.index(path)
    except ValueError:
        return len(LONGEST_FIRST)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=_send_order)  # stable: each file's tests stay together, in order
    for item in items:
        obj = getattr(item, "obj", None)
        if obj is not None and inspect.iscoroutinefunction(obj) and not getattr(
                item.get_closest_marker("allow_leaked_tasks"), "name", None):
            item.obj = _guard(obj)  # type: ignore[attr-defined]


@pytest.fixture(scope="module")
def listener() -> Iterator[socket.socket]:
    """A socket on a free 127.0.0.1 port that listens and must never see a connection
    (non-blocking: `accept()` raising BlockingIOError says nobody came)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    sock.setblocking(False)
    try:
        yield sock
    finally:
        sock.close()


@pytest.fixture
async def rec() -> AsyncIterator[RecordingSim]:
    """A simulated Modbus controller (bearing and ambient at 20 °C) that records
    every offset written to it, stopped after the test."""
    from tests.faults.daemon_run import RecordingSim

    r = RecordingSim()
    await r.start()
    try:
        yield r
    finally:
        await r.stop()
