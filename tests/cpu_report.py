"""Opt-in: the CPU each test file costs, not its wall time (``-p tests.cpu_report
--cpu-report=FILE``). Per test (setup, call and teardown) the process's own CPU
(`time.process_time`, every thread of the worker) plus what its waited-for
children used (``RUSAGE_CHILDREN``: the ``compd`` processes a test starts); each
xdist worker appends its rows to FILE (``file<TAB>test<TAB>cpu_s``), and the
controller prints the sum per file, largest first, at the end. Collection and
the workers' start are not in it: they belong to no test."""

from __future__ import annotations

import collections
import os
import resource
import time
from collections.abc import Generator
from pathlib import Path

import pytest


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--cpu-report", default=None, metavar="FILE",
                     help="append each test's CPU seconds to FILE and print them per file")


def _cpu_s() -> float:
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item) -> Generator[None, None, None]:
    path = item.config.getoption("--cpu-report")
    if path is None:
        yield
        return
    start = _cpu_s()
    yield
    used = _cpu_s() - start
    with open(path, "a", encoding="utf-8") as out:
        out.write(f"{item.location[0]}\t{item.nodeid}\t{used:.3f}\n")


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter,
                            config: pytest.Config) -> None:
    path = config.getoption("--cpu-report")
    if path is None or hasattr(config, "workerinput") or not os.path.exists(path):
        return
    per_file: dict[str, float] = collections.defaultdict(float)
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        name, _, used = line.split("\t")
        per_file[name] += float(used)
    terminalreporter.write_sep("-", f"CPU-s per test file ({sum(per_file.values()):.1f} in tests)")
    for name, cpu_s in sorted(per_file.items(), key=lambda kv: -kv[1])[:40]:
        terminalreporter.write_line(f"{cpu_s:8.2f}  {name}")
