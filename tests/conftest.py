"""Project-wide test rules: warnings are errors (pyproject), an async test
that leaves asyncio tasks behind fails, and bytecode is compiled once a run."""

from __future__ import annotations

import asyncio
import functools
import inspect
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Coroutine
from typing import Any

import pytest
from hypothesis import settings

# Property tests search the same examples on every run (a fixed seed per test):
# a new counterexample is found when a test or its code changes, not at random
# in somebody else's CI run. HYPOTHESIS_PROFILE=explore searches afresh.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def pytest_configure(config: pytest.Config) -> None:
    """With PYTHONDONTWRITEBYTECODE set (no .pyc beside the sources), every
    process of the run would compile every module it imports again: each xdist
    worker rewrites and compiles every test module (about 7 of the 11 CPU-s of a
    collection), each `compd` process a test starts its 150 modules (about 0.1
    CPU-s of its 0.4). The run writes its bytecode to a directory of its own
    instead (PYTHONPYCACHEPREFIX, inherited by the workers and every process
    they start), removed at the end: the tree stays as clean as the setting
    asks, and each module is compiled once a run."""
    if not sys.dont_write_bytecode or sys.pycache_prefix is not None:
        return
    prefix = tempfile.mkdtemp(prefix="compd-tests-pyc-")
    before = {name: os.environ.get(name)
              for name in ("PYTHONDONTWRITEBYTECODE", "PYTHONPYCACHEPREFIX")}

    def restore() -> None:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        sys.dont_write_bytecode, sys.pycache_prefix = True, None
        shutil.rmtree(prefix, ignore_errors=True)

    config.add_cleanup(restore)
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    os.environ["PYTHONPYCACHEPREFIX"] = prefix
    sys.dont_write_bytecode, sys.pycache_prefix = False, prefix


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


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        obj = getattr(item, "obj", None)
        if obj is not None and inspect.iscoroutinefunction(obj) and not getattr(
                item.get_closest_marker("allow_leaked_tasks"), "name", None):
            item.obj = _guard(obj)  # type: ignore[attr-defined]
