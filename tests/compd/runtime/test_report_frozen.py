"""The report and the config are deep-frozen: every sink reads the same values,
and a sink that tries to change them (a bug) gets an error, logged as its
``cycle_error``, never a changed report or config for the sinks after it."""

from __future__ import annotations

import asyncio
import dataclasses
import enum
from collections.abc import Callable
from pathlib import Path
from types import MappingProxyType
from typing import Any

from compd.config.loader import load_config
from compd.core.plan import Row
from compd.runtime.sinks.base import CycleSink, Tick
from tests.configs import write_config
from tests.harness import memory_daemon

EPOCH = 1_700_000_000.0


def mutable_parts(obj: Any, where: str = "") -> list[str]:
    """Where in `obj` a value could be changed in place (empty: deep-frozen)."""
    if obj is None or isinstance(obj, bool | int | float | str | bytes | enum.Enum):
        return []
    if isinstance(obj, MappingProxyType):
        return [p for k, v in obj.items() for p in mutable_parts(v, f"{where}[{k!r}]")]
    if isinstance(obj, tuple):
        names = getattr(obj, "_fields", None) or [str(i) for i in range(len(obj))]
        return [p for n, v in zip(names, obj, strict=True)
                for p in mutable_parts(v, f"{where}.{n}")]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        own = [] if type(obj).__dataclass_params__.frozen else [where]  # type: ignore[attr-defined]
        return own + [p for f in dataclasses.fields(obj)
                      for p in mutable_parts(getattr(obj, f.name), f"{where}.{f.name}")]
    return [f"{where}: {type(obj).__name__}"]


class _Vandal(CycleSink):
    """Fed first: tries to change the report and the config; counts what it could."""

    stage = "vandal"

    def __init__(self) -> None:
        self.changed: list[str] = []
        self.refused = 0
        self.rows: list[Row] = []

    def _try(self, what: str, change: Callable[[], object]) -> None:
        try:
            change()
        except (TypeError, AttributeError):
            self.refused += 1
        else:
            self.changed.append(what)

    def feed(self, tick: Tick) -> None:
        row, cfg = tick.row, tick.cfg
        self.rows.append(row)
        attempts: dict[str, Callable[[], object]] = {
            "row.writes": lambda: row.writes.__setitem__("offset", 1e6),  # type: ignore[index]
            "row.channels": lambda: row.channels.__setitem__("bearing", -1.0),  # type: ignore[index]
            "row.stage_um": lambda: setattr(row, "stage_um", 1e6),
            "cfg.channels": lambda: cfg.channels.pop("bearing"),  # type: ignore[attr-defined]
            "cfg.outputs": lambda: cfg.outputs.__setitem__("offset", None),  # type: ignore[index]
            "cfg.probes": lambda: cfg.probes.__setitem__("x", None),  # type: ignore[index]
            "cfg.states": lambda: cfg.states.__setitem__("x", None),  # type: ignore[index]
            "cfg.path": lambda: setattr(cfg, "path", Path("/elsewhere")),
        }
        for event in row.events:
            attempts[f"event {event.name}"] = (
                lambda e=event: e.fields.__setitem__("vandal", True))  # type: ignore[misc]
        for what, change in attempts.items():
            self._try(what, change)


async def test_a_sink_cannot_change_the_report_or_the_config(tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, "127.0.0.1:1", time_scale=1.0))
    daemon, clock, driver = memory_daemon(cfg, epoch=EPOCH)
    vandal = _Vandal()
    daemon.sinks.insert(0, vandal)
    task = asyncio.create_task(daemon.run())
    await clock.cycle_done(1)
    for k in range(1, 5):
        driver.set("bearing", 20.0 + k)
        clock.tick()
        await clock.cycle_done(k + 1)
    daemon.request_stop()
    assert await task == 0
    assert vandal.changed == []
    # eight attempts a cycle, and one more for each event (the first cycle has some)
    assert vandal.refused > 8 * len(vandal.rows) >= 8 * 5
    assert any(row.events for row in vandal.rows)
    assert set(cfg.channels) == {"bearing", "ambient"} and "offset" in cfg.outputs
    # and nothing in any report can be changed in place
    assert [p for row in vandal.rows for p in mutable_parts(row)] == []


def test_the_loaded_config_holds_read_only_mappings(tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, "127.0.0.1:1"))
    for name in ("channels", "outputs", "probes", "states"):
        assert isinstance(getattr(cfg, name), MappingProxyType), name
    # a replaced config (a reload's, a test's) is as read-only as a loaded one
    again = dataclasses.replace(cfg, channels={"bearing": cfg.channels["bearing"]})
    assert isinstance(again.channels, MappingProxyType)


def test_the_axes_of_a_loaded_config_are_read_only(tmp_path: Path) -> None:
    from tests.compd.axes_helpers import write_axes_config

    cfg = load_config(write_axes_config(tmp_path))
    assert cfg.axes is not None and cfg.axes.models
    for name in ("reference_mm", "quanta", "stages", "reference_quantum_mm", "models"):
        assert isinstance(getattr(cfg.axes, name), MappingProxyType), name
