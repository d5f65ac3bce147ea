"""X and Z compensated at once on a real, headless LinuxCNC
(`drivers.sim.linuxcnc_machine`): each axis's external offset (``axis.x.eoffset``,
``axis.z.eoffset``) driven by compd's HAL component in the same write, X's offset
evaluated at X's position as LinuxCNC reports it (``axis.x.pos-cmd``).

One LinuxCNC for the module, held under the machine's LinuxCNC lock
(`drivers.sim.linuxcnc_host`); skipped with the reason where ``linuxcnc-uspace``
is absent or a LinuxCNC this run did not start runs. X is moved by MDI lines.
"""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest
import pytest_asyncio

from drivers.linuxcnc import LinuxCncDriver
from drivers.sim.linuxcnc_machine import (
    ForeignLinuxCnc,
    LinuxCncBusy,
    LinuxCncSimController,
    unavailable,
)

WHY_NOT = unavailable()
pytestmark = [pytest.mark.skipif(WHY_NOT is not None, reason=str(WHY_NOT)),
              pytest.mark.asyncio(loop_scope="module"),
              pytest.mark.timeout(300, func_only=True)]

#: how close motion's external offset planner comes to the request before it stops
SETTLED_UM = 1e-3


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def lcnc() -> AsyncIterator[LinuxCncSimController]:
    sim = LinuxCncSimController()
    try:
        await sim.start()
    except (ForeignLinuxCnc, LinuxCncBusy) as exc:
        pytest.skip(str(exc))
    try:
        yield sim
    finally:
        await sim.stop()


async def test_x_and_z_eoffsets_are_written_together(lcnc: LinuxCncSimController) -> None:
    """One driver, one write: X's and Z's external offsets both applied, each on its
    own signals and counts, and each read back on its own axis."""
    outputs = {"offset": lcnc.outputs_map["offset"], "x_offset": lcnc.x_offset}
    driver = LinuxCncDriver(lcnc.endpoint, {"x_pos": lcnc.x_position}, outputs,
                            timeout_s=10.0, connect_timeout_s=60.0, component=lcnc.component)
    try:
        await driver.connect()
        assert driver.eoffset_scales == pytest.approx({"offset": 1e-4, "x_offset": 1e-4})
        await driver.write({"offset": 4.2, "x_offset": -7.3})
        hal = await lcnc.settled_axes()
        assert hal["offset_um"] == pytest.approx(4.2, abs=SETTLED_UM)
        assert hal["x_offset_um"] == pytest.approx(-7.3, abs=SETTLED_UM)
        got = await driver.read(["offset", "x_offset", "x_pos"])
        assert got["offset"].value == pytest.approx(4.2, abs=SETTLED_UM)
        assert got["x_offset"].value == pytest.approx(-7.3, abs=SETTLED_UM)
        # X alone: Z keeps its offset
        await driver.write({"x_offset": 2.5})
        hal = await lcnc.settled_axes()
        assert (hal["x_offset_um"], hal["offset_um"]) == pytest.approx((2.5, 4.2),
                                                                      abs=SETTLED_UM)
        await driver.write({"offset": 0.0, "x_offset": 0.0})
        hal = await lcnc.settled_axes()
        assert (hal["x_offset_um"], hal["offset_um"]) == pytest.approx((0.0, 0.0),
                                                                      abs=SETTLED_UM)
    finally:
        await driver.close()
