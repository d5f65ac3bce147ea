"""The config's per-axis temperature-compensation outputs: ``[output.axes.<axis>]``.

For a controller that takes the compensation line per axis as its own
parameters (SINUMERIK SD43900/43910/43920, TwinCAT P-AXIS-00272..274;
`drivers.temp_comp`), each axis X, Y, Z names where its three parameters
live, the reference position compd writes, and what compd may send::

    [output.axes.x]
    value = { node = "ns=2;s=Machine.X.$SA_TEMP_COMP_ABS_VALUE", scale = 1000.0 }
    slope = { node = "ns=2;s=Machine.X.$SA_TEMP_COMP_SLOPE", scale = 1e6 }
    reference = { node = "ns=2;s=Machine.X.$SA_TEMP_COMP_REF_POSITION" }
    reference_mm = 0.0          # the line's reference position (the fixed bearing)
    value_limit_um = 100.0      # |value| ≤ this
    slope_limit_um_m = 50.0     # |slope| ≤ this
    slew_um_s = 1.0             # the value's rate limit (µm/s)
    slope_slew_um_m_s = 0.5     # the slope's rate limit (µm/m per s)
    deadband_um = 0.0           # optional, as [output] deadband_um
    slope_deadband_um_m = 0.0   # optional
    model = { file = "x_value.toml" }        # the value's model, as [model]
    slope_model = { file = "x_slope.toml" }  # optional: without it the slope is 0

Each address is the protocol's own address model with ``scale`` turning the
controller's unit into µm, µm/m and mm (engineering value = raw · scale). The
checks are the offset's: each address valid for the protocol
(`compd.config.address_check`), writable by a client, able to hold ±its
limit (`compd.config.output_range.check_range`), and sharing no controller
memory with another output (`drivers.footprint.first_clash`). Every refusal
is a `ConfigError` naming the key (``output.axes.x.slope``).

A controller without such parameters (a plain offset register over Modbus,
FOCAS) takes an axis as one offset evaluated at the axis's present position
(`compd.core.axes`)::

    [output.axes.x]
    position = "x_pos"          # a [channels] channel, unit "mm", with stale_after_s
    offset = { kind = "holding", address = 50, type = "float32" }
    reference_mm = 0.0
    value_limit_um = 100.0
    slope_limit_um_m = 50.0
    ...                         # rates, deadbands and models as above

The offset address is checked as the others, against the most the line can
reach over the position channel's range (`PositionalAxis.offset_limit_um`).
On LinuxCNC (no such parameters: `NO_PARAMETERS`, the parameter form is
refused) the offset is the axis's own external offset, one writer per axis::

    [channels.x_pos]
    address = { kind = "get", hal = "axis.x.pos-cmd" }
    unit = "mm"
    range = [-100.0, 100.0]
    stale_after_s = 5.0

    [output.axes.x]
    position = "x_pos"
    offset = { kind = "eoffset", axis = "x", counts_net = "compd-x-eoffset-counts",
               enable_net = "compd-x-eoffset-enable", scale = 0.1 }

On a SINUMERIK (OPC UA, S7) the tool direction takes a value alone, the
per-channel SD42960 ``$SC_TOOL_TEMP_COMP`` (mm) that the controller applies
along the tool's orientation (MD20390 ``$MC_TOOL_TEMP_COMP_ON``)::

    [output.axes.tool]
    value = { node = "ns=2;s=Machine.Channel.$SC_TOOL_TEMP_COMP", scale = 1000.0 }
    value_limit_um = 100.0
    slew_um_s = 1.0
    model = { file = "tool.toml" }

`parse_axis_outputs` returns `AxisOutputSet`: the drivers' `AxisOutputs`
(names, writes, read-back), each axis's reference position and its output
stage's rates and deadbands (`AxisStage`). The two models (``model``,
``slope_model``: a model file or inline terms, the ``[model]`` table's form)
are built and checked by `compd.config.loader` (they need the config's
channels and period), which puts them in `AxisOutputSet.models`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from compd.config.address_check import quantum, validate_address
from compd.config.output_range import check_range
from compd.errors import ConfigError
from drivers.addresses import Address, LinuxCncEoffset, ModbusAddress
from drivers.footprint import first_clash
from drivers.temp_comp import (
    AXES,
    PARAMETERS,
    UNITS,
    AxisAddresses,
    AxisCompensation,
    AxisLimits,
    AxisOutputs,
    output_name,
)

if TYPE_CHECKING:
    from models.compensation import CompensationModel

#: the keys of one axis's table besides its three addresses and its models
SETTINGS: tuple[str, ...] = ("reference_mm", "value_limit_um", "slope_limit_um_m",
                             "slew_um_s", "slope_slew_um_m_s", "deadband_um",
                             "slope_deadband_um_m")
#: an axis's models (built by `compd.config.loader`: a file or inline terms)
MODEL_KEYS: tuple[str, ...] = ("model", "slope_model")
#: an axis written as an offset at its position: the channel and the offset address
POSITIONAL: tuple[str, ...] = ("position", "offset")
#: the tool direction's table name, its keys, and the protocols that have it
TOOL = "tool"
TOOL_KEYS: tuple[str, ...] = ("value", "value_limit_um", "slew_um_s", "deadband_um", "model")
TOOL_PROTOCOLS: frozenset[str] = frozenset({"opcua", "s7"})


@dataclass(frozen=True, slots=True)
class ToolOutput:
    """The tool direction's value (SD42960) and its limit."""

    value: Address
    limits: AxisLimits
    quantum_um: float


@dataclass(frozen=True, slots=True)
class PositionChannel:
    """What an axis's position channel must give (`parse_axis_outputs`): its range (mm)
    and whether it has an age bound (``stale_after_s``)."""

    range_mm: tuple[float, float]
    stale_after_s: float | None


@dataclass(frozen=True, slots=True)
class PositionalAxis:
    """An axis written as one offset at its position (see the module)."""

    offset: Address
    position: str
    limits: AxisLimits
    #: the most |value + slope·(x - reference)/1000| reaches over the position's range
    offset_limit_um: float
    #: the offset address's grid (µm; 0: a float)
    offset_quantum_um: float


@dataclass(frozen=True, slots=True)
class AxisStage:
    """One axis's output stage settings: the rate limit and deadband of its
    value (µm/s, µm) and of its slope (µm/m per s, µm/m); None: not given
    (the loader requires a rate for each parameter a model drives)."""

    slew_um_s: float | None = None
    slope_slew_um_m_s: float | None = None
    deadband_um: float = 0.0
    slope_deadband_um_m: float = 0.0


@dataclass(frozen=True, slots=True)
class AxisModels:
    """The models of one axis: its value's (µm at the reference position) and
    its slope's (µm/m; None: the slope is held at 0)."""

    value: CompensationModel
    slope: CompensationModel | None = None
    #: each model's identity (`compd.config.loader.model_sha256`; "" for none): a
    #: checkpoint's or reload's model state is taken only by the same model
    value_sha256: str = ""
    slope_sha256: str = ""
#: protocols whose controllers have no such parameters (their axes take an offset
#: evaluated at the axis position instead)
NO_PARAMETERS: frozenset[str] = frozenset({"linuxcnc"})


@dataclass(frozen=True)
class AxisOutputSet:
    """The per-axis outputs of one config."""

    outputs: AxisOutputs
    #: axis -> the reference position written with every line, mm
    reference_mm: Mapping[str, float]
    #: axis -> the steps the controller holds its value (µm) and slope (µm/m) in
    #: (0: a float, no grid; TwinCAT: 0.1 µm and 1 µm/m), for the output stage to
    #: put each on the controller's grid as it does the offset
    quanta: Mapping[str, tuple[float, float]]
    #: axis -> its output stage's rates and deadbands
    stages: Mapping[str, AxisStage] = field(default_factory=dict)
    #: axis -> the step the controller holds its reference position in (mm; 0: a float)
    reference_quantum_mm: Mapping[str, float] = field(default_factory=dict)
    #: axis -> its models (set by `compd.config.loader`; empty from `parse_axis_outputs`)
    models: Mapping[str, AxisModels] = field(default_factory=dict)
    #: axis -> the axes written as one offset at their position
    positional: Mapping[str, PositionalAxis] = field(default_factory=dict)
    #: the tool direction (a value alone), None: not configured
    tool: ToolOutput | None = None

    def __post_init__(self) -> None:
        # read-only views of copies: the config is one value every sink reads
        for name in ("reference_mm", "quanta", "stages", "reference_quantum_mm", "models"):
            object.__setattr__(self, name, MappingProxyType(dict(getattr(self, name))))

    @property
    def axes(self) -> tuple[str, ...]:
        """The configured axes, in X, Y, Z order, then the tool direction."""
        found = tuple(a for a in AXES if a in self.outputs.addresses or a in self.positional)
        return (*found, TOOL) if self.tool is not None else found

    def limits(self, axis: str) -> AxisLimits:
        if axis == TOOL and self.tool is not None:
            return self.tool.limits
        p = self.positional.get(axis)
        return p.limits if p is not None else self.outputs.limits[axis]

    def driver_outputs(self) -> dict[str, Address]:
        """Output name -> address of every axis, for the driver's outputs table."""
        tool = {output_name(TOOL, "value"): self.tool.value} if self.tool is not None else {}
        return {**self.outputs.outputs(),
                **{output_name(a, "offset"): p.offset for a, p in self.positional.items()},
                **tool}

    def line(self, axis: str, value_um: float, slope_um_m: float) -> AxisCompensation:
        """The line to write for `axis` at its configured reference position."""
        return AxisCompensation(value_um, slope_um_m, self.reference_mm[axis])


def _number(key: str, v: Any, *, positive: bool) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(key, f"must be a finite number, got {v!r}")
    if positive and v <= 0.0:
        raise ConfigError(key, f"must be > 0, got {v!r}")
    return float(v)


def _writable(key: str, addr: Address) -> None:
    if isinstance(addr, ModbusAddress) and addr.kind != "holding":
        raise ConfigError(key, "input registers are read-only for a client; use holding "
                               "registers")
    if addr.footprint() is None:  # a FOCAS diagnosis number or spindle load: read only
        raise ConfigError(key, f"{addr.describe()} cannot be written by a client")


def parse_axis_outputs(protocol: str, table: Mapping[str, Any], *,
                       others: Mapping[str, Address] | None = None,
                       positions: Mapping[str, PositionChannel] | None = None,
                       key: str = "output.axes") -> AxisOutputSet:
    """``[output.axes]`` of a config whose controller speaks `protocol`, checked
    (see the module); `others` are the config's other addresses by key
    (``output.offset``, ``channels.bearing.address``), which no axis parameter
    may overlap; `positions` the channels in mm an axis may read its position
    from. `ConfigError` names the key."""
    addresses: dict[str, AxisAddresses] = {}
    limits: dict[str, AxisLimits] = {}
    refs: dict[str, float] = {}
    quanta: dict[str, tuple[float, float]] = {}
    stages: dict[str, AxisStage] = {}
    positional: dict[str, PositionalAxis] = {}
    tool: ToolOutput | None = None
    uses = [u for k, a in (others or {}).items()
            for u in a.uses(k, written=k.startswith("output."))]
    for axis, doc in table.items():
        at = f"{key}.{axis}"
        if axis not in (*AXES, TOOL):
            raise ConfigError(at, f"unknown axis; known: {', '.join((*AXES, TOOL))}")
        if not isinstance(doc, Mapping):
            raise ConfigError(at, "must be a table")
        if axis == TOOL:
            tool = _tool(protocol, at, doc, uses)
            stages[axis] = _stage(at, doc, tool.limits)
            refs[axis] = 0.0
            quanta[axis] = (tool.quantum_um, 0.0)
            continue
        if "position" not in doc and protocol in NO_PARAMETERS:
            raise ConfigError(at, f"a {protocol} controller has no temperature-compensation "
                                  "parameters per axis: write the axis as an offset at its "
                                  "position (position = a channel, offset = an eoffset "
                                  f"address with axis = \"{axis}\")")
        if "position" in doc:
            positional[axis] = _positional(protocol, at, doc, positions or {}, uses)
            if protocol == "linuxcnc":
                _own_eoffset(at, axis, positional[axis].offset, others or {})
            stages[axis] = _stage(at, doc, positional[axis].limits)
            refs[axis] = _number(f"{at}.reference_mm", doc.get("reference_mm", 0.0),
                                 positive=False)
            continue
        unknown = sorted(set(doc) - set(PARAMETERS) - set(SETTINGS) - set(MODEL_KEYS))
        if unknown:
            raise ConfigError(f"{at}.{unknown[0]}", "unknown key; known: "
                              + ", ".join((*PARAMETERS, *SETTINGS, *MODEL_KEYS)))
        missing = [k for k in (*PARAMETERS, "value_limit_um", "slope_limit_um_m")
                   if k not in doc]
        if missing:
            raise ConfigError(f"{at}.{missing[0]}", "required key is missing")
        lim = AxisLimits(_number(f"{at}.value_limit_um", doc["value_limit_um"], positive=True),
                         _number(f"{at}.slope_limit_um_m", doc["slope_limit_um_m"],
                                 positive=True))
        ref = _number(f"{at}.reference_mm", doc.get("reference_mm", 0.0), positive=False)
        stages[axis] = _stage(at, doc, lim)
        typed: dict[str, Address] = {}
        for p in PARAMETERS:
            given = doc[p]
            if not isinstance(given, Mapping):
                raise ConfigError(f"{at}.{p}", "must be an address table")
            addr = validate_address(protocol, dict(given), f"{at}.{p}")
            _writable(f"{at}.{p}", addr)
            typed[p] = addr
            uses.extend(addr.uses(f"{at}.{p}", written=True))
        bounds = {"value": (lim.value_limit_um, f"value_limit_um = {lim.value_limit_um:g}"),
                  "slope": (lim.slope_limit_um_m,
                            f"slope_limit_um_m = {lim.slope_limit_um_m:g}"),
                  "reference": (abs(ref), f"reference_mm = {ref:g}")}
        for p, addr in typed.items():
            bound, what = bounds[p]
            check_range(f"{at}.{p}", addr, -bound, bound, what, unit=f" {UNITS[p]}")
        addresses[axis] = AxisAddresses(**typed)
        limits[axis] = lim
        refs[axis] = ref
        quanta[axis] = (quantum(typed["value"]), quantum(typed["slope"]))
    clash = first_clash(uses)
    if clash is not None:
        raise ConfigError(clash.second.key, clash.reason())
    return AxisOutputSet(AxisOutputs(addresses, limits, key=key), refs, quanta, stages,
                         {a: quantum(addresses[a].reference) for a in addresses},
                         positional=positional, tool=tool)


def _tool(protocol: str, at: str, doc: Mapping[str, Any], uses: list[Any]) -> ToolOutput:
    """The tool direction: a SINUMERIK's SD42960, a value alone (see the module)."""
    if protocol not in TOOL_PROTOCOLS:
        raise ConfigError(at, "the tool direction is a SINUMERIK setting (SD42960 "
                              "$SC_TOOL_TEMP_COMP): protocol opcua or s7")
    unknown = sorted(set(doc) - set(TOOL_KEYS))
    if unknown:
        raise ConfigError(f"{at}.{unknown[0]}", "unknown key; the tool direction takes: "
                          + ", ".join(TOOL_KEYS))
    missing = [k for k in ("value", "value_limit_um") if k not in doc]
    if missing:
        raise ConfigError(f"{at}.{missing[0]}", "required key is missing")
    limit = _number(f"{at}.value_limit_um", doc["value_limit_um"], positive=True)
    given = doc["value"]
    if not isinstance(given, Mapping):
        raise ConfigError(f"{at}.value", "must be an address table")
    addr = validate_address(protocol, dict(given), f"{at}.value")
    _writable(f"{at}.value", addr)
    check_range(f"{at}.value", addr, -limit, limit, f"value_limit_um = {limit:g}", unit=" µm")
    uses.extend(addr.uses(f"{at}.value", written=True))
    # the slope's limit is immaterial: the tool direction has none (it stays 0)
    return ToolOutput(addr, AxisLimits(limit, 1.0), quantum(addr))


def _limits(at: str, doc: Mapping[str, Any]) -> AxisLimits:
    return AxisLimits(_number(f"{at}.value_limit_um", doc["value_limit_um"], positive=True),
                      _number(f"{at}.slope_limit_um_m", doc["slope_limit_um_m"],
                              positive=True))


def _positional(protocol: str, at: str, doc: Mapping[str, Any],
                positions: Mapping[str, PositionChannel], uses: list[Any]) -> PositionalAxis:
    """An axis written as one offset at its position: its channel (unit mm, an age
    bound), its offset address (writable, able to hold the line over the channel's
    range, overlapping nothing: `uses` gets its footprint)."""
    known = (*POSITIONAL, *SETTINGS, *MODEL_KEYS)
    unknown = sorted(set(doc) - set(known))
    if unknown:
        what = "an axis with a position takes an offset, not the line's parameters" \
            if unknown[0] in PARAMETERS else "unknown key; known: " + ", ".join(known)
        raise ConfigError(f"{at}.{unknown[0]}", what)
    missing = [k for k in (*POSITIONAL, "value_limit_um", "slope_limit_um_m") if k not in doc]
    if missing:
        raise ConfigError(f"{at}.{missing[0]}", "required key is missing")
    name = doc["position"]
    channel = positions.get(name) if isinstance(name, str) else None
    if channel is None:
        raise ConfigError(f"{at}.position", f"must name a [channels] channel with unit "
                          f"\"mm\" (the axis's position), got {name!r}")
    if channel.stale_after_s is None:
        raise ConfigError(f"channels.{name}.stale_after_s", "required for an axis position "
                          f"({at}.position): the offset is only as good as the position "
                          "is recent")
    lim = _limits(at, doc)
    ref = _number(f"{at}.reference_mm", doc.get("reference_mm", 0.0), positive=False)
    lo, hi = channel.range_mm
    bound = lim.value_limit_um + lim.slope_limit_um_m * max(abs(lo - ref), abs(hi - ref)) / 1000.0
    given = doc["offset"]
    if not isinstance(given, Mapping):
        raise ConfigError(f"{at}.offset", "must be an address table")
    addr = validate_address(protocol, dict(given), f"{at}.offset")
    _writable(f"{at}.offset", addr)
    check_range(f"{at}.offset", addr, -bound, bound,
                f"value_limit_um + slope_limit_um_m over channels.{name}.range = {bound:g}",
                unit=" µm")
    uses.extend(addr.uses(f"{at}.offset", written=True))
    return PositionalAxis(addr, name, lim, bound, quantum(addr))


def _own_eoffset(at: str, axis: str, addr: Address, others: Mapping[str, Address]) -> None:
    """On LinuxCNC an axis's offset is that axis's external offset, and no other
    output (``output.offset``) writes it: two writers would each count against the
    other's changes. (Two axes cannot share one: each names its own axis.)"""
    if not isinstance(addr, LinuxCncEoffset):
        raise ConfigError(f"{at}.offset", f"on LinuxCNC an axis's offset is its external "
                          f"offset: kind = \"eoffset\", axis = \"{axis}\"")
    if addr.axis != axis:
        raise ConfigError(f"{at}.offset.axis", f"must be {axis!r} (the external offset of "
                          f"the axis it compensates), got {addr.axis!r}")
    for key, other in others.items():
        if (key.startswith("output.") and isinstance(other, LinuxCncEoffset)
                and other.axis == axis):
            raise ConfigError(f"{at}.offset", f"axis {axis.upper()}'s external offset is "
                              f"written by {key} already: one eoffset per axis")


def _stage(at: str, doc: Mapping[str, Any], lim: AxisLimits) -> AxisStage:
    """An axis's rates (> 0 when given) and deadbands (>= 0, below the limit)."""
    rates = {k: _number(f"{at}.{k}", doc[k], positive=True)
             for k in ("slew_um_s", "slope_slew_um_m_s") if k in doc}
    bands: dict[str, float] = {}
    for k, limit in (("deadband_um", lim.value_limit_um),
                     ("slope_deadband_um_m", lim.slope_limit_um_m)):
        v = _number(f"{at}.{k}", doc.get(k, 0.0), positive=False)
        if v < 0.0 or v >= limit:
            raise ConfigError(f"{at}.{k}", f"must be >= 0 and below the limit ({limit:g}), "
                                           f"got {v:g}")
        bands[k] = v
    return AxisStage(**rates, **bands)


__all__ = [
    "MODEL_KEYS",
    "NO_PARAMETERS",
    "POSITIONAL",
    "SETTINGS",
    "TOOL",
    "AxisModels",
    "AxisOutputSet",
    "AxisStage",
    "PositionChannel",
    "PositionalAxis",
    "ToolOutput",
    "parse_axis_outputs",
]
