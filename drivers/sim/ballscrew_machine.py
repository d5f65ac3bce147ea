"""The ball-screw axis behind a simulated controller: the controller's own
temperature-compensation line applied to the axis's growth.

The axis grows as `drivers.sim.ballscrew` simulates it (noise-free here: the
truth), e(x) = a + b·(x - x0)/1000 µm. Each measurement reads the line the
controller holds for the axis from its own memory (`compensation(axis)` of
the OPC UA, S7 or Modbus simulated controller: what a client wrote to
SD43900/43910/43920 or P-AXIS-00272..274) and gives the error left at each
position along the travel, as a laser at those positions would see it::

    error(x) = e(x) - (value + slope·(x - reference)/1000)        µm

So whatever writes the parameters (the daemon, a test playing it) is judged
at every position by the controller's own arithmetic, after its encoding.
`tick()` moves one period of machine time on; `measure()` measures now.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from drivers.sim.ballscrew import (
    DEFAULT_POSITIONS_MM,
    TEMPERATURES,
    AxisProgram,
    BallscrewParams,
    simulate_ballscrew,
)
from drivers.temp_comp import AxisCompensation


class CompensatingController(Protocol):
    """A simulated controller holding per-axis compensation parameters."""

    async def compensation(self, axis: str) -> AxisCompensation: ...


class BallscrewMachine:
    """One ball-screw axis of a simulated controller (see the module)."""

    def __init__(self, controller: CompensatingController, *, hours: float,
                 period_s: float = 300.0, seed: int = 0, program: AxisProgram | None = None,
                 positions_mm: Sequence[float] = DEFAULT_POSITIONS_MM,
                 params: BallscrewParams | None = None, axis: str = "x") -> None:
        self.controller = controller
        self.axis = axis
        self.params = params if params is not None else BallscrewParams()
        self.positions_mm = tuple(float(x) for x in positions_mm)
        self._truth = simulate_ballscrew(hours, period_s=period_s, seed=seed, program=program,
                                         positions_mm=self.positions_mm, params=self.params,
                                         probe_noise_um=0.0)
        self.rows = len(self._truth["time_s"])
        #: the present row of the simulated record (0: at rest)
        self.row = 0

    @property
    def time_s(self) -> float:
        return float(self._truth["time_s"][self.row])

    @property
    def value_um(self) -> float:
        """The true growth at the reference position x0, µm."""
        return float(self._truth["value_um"][self.row])

    @property
    def slope_um_m(self) -> float:
        """The true growth per metre of travel, µm/m."""
        return float(self._truth["slope_um_m"][self.row])

    @property
    def x0_mm(self) -> float:
        return self.params.x0_mm

    def temperatures(self) -> dict[str, float]:
        """The sensors now (nut, screw_bearing, column, ambient; 0.1 K)."""
        return {name: float(self._truth[name][self.row]) for name in TEMPERATURES}

    def growth_um(self, x_mm: float) -> float:
        """The axis's true growth at position `x_mm` now, µm."""
        return self.value_um + self.slope_um_m * (x_mm - self.x0_mm) / 1000.0

    async def measure(self) -> dict[float, float]:
        """The error left at each position now, under the controller's line, µm."""
        line = await self.controller.compensation(self.axis)
        return {x: self.growth_um(x) - line.at(x) for x in self.positions_mm}

    def step(self) -> None:
        """Move one period on, measuring nothing (a controller without the line's
        parameters: the caller judges its offset at `growth_um`); `RuntimeError`
        past the last row."""
        if self.row + 1 >= self.rows:
            raise RuntimeError(f"the simulated record ends at {self.time_s:g} s")
        self.row += 1

    async def tick(self) -> dict[float, float]:
        """Move one period on, then `measure()`; `RuntimeError` past the last row."""
        self.step()
        return await self.measure()


__all__ = ["BallscrewMachine", "CompensatingController"]
