"""The test machine: a simulated machine tool and its controllers, not I/O of ours.

Nothing here is part of compd's own I/O path (that is `drivers/*`, one
driver per protocol): this package plays the *other* side of the wire, the
machine and its CNC/PLC, so that tests, `compd demo` and the HIL bench
exercise the daemon against real servers. A thermal plant (`plant.py`, not
one of our model structures) is fronted by one real server per protocol on
127.0.0.1 (found by protocol name through `drivers.protocols`), or drives a
real controller as a client on a HIL bench (`drive.py`).

Standard names used by every simulated controller:

channels (read by the daemon)
    ``bearing``  spindle front bearing temperature, °C (0.1 K quantised)
    ``motor``    spindle motor temperature, °C
    ``column``   column temperature, °C
    ``table``    rotary table bearing temperature, °C
    ``ambient``  ambient (room) temperature, °C
    ``spindle_rpm`` spindle speed, rpm
    ``power_kw`` spindle drive power, kW
    ``growth_um`` thermal Z growth at the tool (what a probe measures), µm
    ``error_um`` Z error at the tool = growth - offset written, µm

outputs (written by the daemon, readable back)
    ``offset``    Z offset, µm
    ``heartbeat`` counter, advanced once per complete valid cycle
    ``status``    status word (bit flags, see compd.core.output)

per-axis temperature compensation (written by the daemon, readable back;
`drivers.temp_comp`: the controller applies value + slope·(x - reference)/1000)
    ``<axis>_comp_value``      µm at the reference position (SD43900 / P-AXIS-00273)
    ``<axis>_comp_slope``      µm/m (SD43910 / P-AXIS-00274)
    ``<axis>_comp_reference``  mm (SD43920 / P-AXIS-00272), for axis x, y, z
"""

CHANNELS: tuple[str, ...] = ("bearing", "motor", "column", "table", "ambient",
                             "spindle_rpm", "power_kw", "growth_um", "error_um")
OUTPUTS: tuple[str, ...] = ("offset", "heartbeat", "status")
#: the per-axis compensation parameters every simulated controller holds
AXIS_OUTPUTS: tuple[str, ...] = tuple(f"{axis}_comp_{p}" for axis in ("x", "y", "z")
                                      for p in ("value", "slope", "reference"))
#: the measuring cycle's values (`compd sim --probe-every-min`, a daemon's
#: ``[adaptation]``): the probe's measured Z deviation (µm: the growth minus the
#: offset in force, plus the probe's noise) and a counter advanced per measurement
PROBES: tuple[str, ...] = ("probe_value", "probe_counter")
