"""The simulated machine whose spindle LinuxCNC drives: the plant turns at the
speed the G-code program running in the headless LinuxCNC commands
(``spindle.0.speed-out``, read each tick before the plant advances), not at a
speed schedule of its own, so the program really makes the heat.

Each tick reads the speed, then steps the plant one `period_s` at it: the
speed a program sets between two ticks takes effect at the next one (at most
one period late, as a sampled drive would see it).
"""

from __future__ import annotations

from drivers.sim.linuxcnc_machine import LinuxCncSimController
from drivers.sim.machine import SimMachine
from drivers.sim.plant import MAX_SPEED_RPM


class LinuxCncSpindleMachine(SimMachine):
    """`SimMachine` with LinuxCNC's commanded spindle speed as its program."""

    def __init__(self, controller: LinuxCncSimController, *, seed: int = 0,
                 period_s: float = 1.0, speedup: float = 1.0, record: bool = False) -> None:
        super().__init__(controller, seed=seed, period_s=period_s, speedup=speedup,
                         record=record)
        self.lcnc = controller
        #: the speed read at the last tick (rpm), the one the plant turned at
        self.rpm = 0.0

    def speed_at(self, t_s: float) -> float:
        return self.rpm

    async def tick(self) -> dict[str, float]:
        # LinuxCNC's S word may exceed what the plant models: clamp, never raise
        self.rpm = min(max(0.0, abs(await self.lcnc.spindle_rpm())), MAX_SPEED_RPM)
        return await super().tick()


__all__ = ["LinuxCncSpindleMachine"]
