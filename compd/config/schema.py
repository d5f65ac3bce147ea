"""The daemon config's sections as pydantic models (extra keys refused).

The building blocks are in `compd.config.section`, ``[telemetry]`` and ``[faces]`` in
`compd.config.face_sections`, ``[adaptation]`` and its bounds in
`compd.config.adaptation_section`, ``[channels.NAME]`` in
`compd.config.channel_section`; every name stays importable from here.

Only the shape of each section and the checks that need no other section
live here; `compd.config.loader` loads the file, runs the cross-section checks
(timeout vs period, addresses against the protocol, the model) and turns
every failure into a `ConfigError` naming the dotted key path.

Example (the full set of sections; `compd/examples/*.toml` are complete)::

    [machine]
    name = "mill-3"
    period_s = 1.0
    time_scale = 1.0          # machine seconds per real second (>1: demo/bench)

    [controller]
    protocol = "modbus"       # opcua | s7 | modbus | focas | linuxcnc
    endpoint = "modbus://127.0.0.1:5020"
    timeout_s = 0.2           # <= 0.5 * period_s / time_scale

    [channels.bearing]
    address = { kind = "input", address = 0, type = "int16", scale = 0.1 }
    unit = "degC"
    range = [-20.0, 120.0]
    max_rate_per_s = 0.5
    stale_after_s = 10.0
    stuck_after_s = 7200.0    # stuck: unchanged this long while others move, or
    stuck_delta_k = 2.0       # unchanged while another temperature moved > 2 K

    [model]
    file = "sp2"              # a path relative to this file, or a bundled model

    [output]
    offset = { kind = "holding", address = 0, type = "float32" }
    limit_um = 200.0
    slew_um_s = 2.0
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

from compd.config.adaptation_section import ADAPTATION_BOUNDS, AdaptationSection, learnt_bounds
from compd.config.channel_section import (
    DEFAULT_STUCK_DELTA_K,
    TEMPERATURE_UNITS,
    UNITS,
    ChannelSection,
)
from compd.config.face_sections import (
    FacesSection,
    HttpFaceSection,
    OpcUaFaceSection,
    TelemetrySection,
)
from compd.config.section import (
    MAX_LIMIT_UM,
    LaxPath,
    PeriodS,
    PositiveS,
    Section,
    bounded,
)
from compd.config.urls import url_credentials
from drivers.endpoint import endpoint_of
from drivers.linuxcnc_options import LinuxCncOptions
from drivers.opcua_policy import OpcUaSecurityRules
from drivers.protocol_options import FocasOptions, S7Options
from drivers.protocols import ProtocolName

#: the sections and bounds that live in the modules beside this one, named here too
__all__ = [
    "ADAPTATION_BOUNDS",
    "DEFAULT_STUCK_DELTA_K",
    "MAX_LIMIT_UM",
    "TEMPERATURE_UNITS",
    "UNITS",
    "AdaptationSection",
    "ChannelSection",
    "FacesSection",
    "HttpFaceSection",
    "OpcUaFaceSection",
    "TelemetrySection",
    "learnt_bounds",
]

#: the protocol names, from the one registry (`drivers.protocols`)
Protocol = ProtocolName

#: output units and their controller units per µm
OUTPUT_UNITS: dict[str, float | None] = {"um": 1.0, "mm": 1e-3, "nm": 1e3, "inch": 1.0 / 25400.0,
                                         "count": None}



class MachineSection(Section):
    name: str = "machine"
    period_s: PeriodS = 1.0
    #: machine seconds per real second: 1.0 in production, > 1 for the demo/bench
    time_scale: PositiveS = 1.0


#: the longest wait between reconnect attempts (real seconds): compensation
#: must resume within 10 s + 2·Ts after a lost link returns
MAX_BACKOFF_CAP_S = 10.0


class BackoffSection(Section):
    """Waits between reconnect attempts (real seconds), doubling from
    `initial_s` up to `cap_s`."""

    initial_s: PositiveS = 0.1
    cap_s: PositiveS = 5.0

    @field_validator("cap_s")
    @classmethod
    def _cap(cls, v: float) -> float:
        if v > MAX_BACKOFF_CAP_S:
            raise ValueError(
                f"at most {MAX_BACKOFF_CAP_S:g} s (got {v:g} s): the driver retries a lost "
                f"link only every cap_s, and compensation must resume within "
                f"{MAX_BACKOFF_CAP_S:g} s + 2 periods after the link returns")
        return v

    @model_validator(mode="after")
    def _order(self) -> BackoffSection:
        if self.cap_s < self.initial_s:
            raise ValueError(f"cap_s ({self.cap_s:g} s) must be >= initial_s "
                             f"({self.initial_s:g} s): the first wait cannot exceed the "
                             f"longest")
        return self


class SecuritySection(OpcUaSecurityRules):
    """OPC UA security: the rules of `drivers.opcua_policy` (the driver's own)
    and where the password comes from: a file or an environment variable,
    never the config itself."""

    model_config = Section.model_config
    password_file: LaxPath | None = None
    password_env: str | None = None
    #: must be true to run with policy "None" (a deliberate choice, not a default)
    insecure: bool = False

    @property
    def has_password(self) -> bool:
        return self.password_file is not None or self.password_env is not None

    @model_validator(mode="before")
    @classmethod
    def _no_inline_password(cls, data: Any) -> Any:
        if isinstance(data, dict) and "password" in data:
            raise ValueError("a password is never written in the config: use password_file "
                             "(a file readable only by the daemon) or password_env "
                             "(the name of an environment variable)")
        return data

    @model_validator(mode="after")
    def _one_source(self) -> SecuritySection:
        if self.password_file is not None and self.password_env is not None:
            raise ValueError("give password_file or password_env, not both")
        if self.policy == "None" and not self.insecure:
            raise ValueError("security policy None sends everything readable and "
                             "unauthenticated: set insecure = true to accept that")
        return self


#: [controller.s7] and [controller.focas]: the drivers' own option models
S7Section = S7Options
FocasSection = FocasOptions
#: [controller.linuxcnc]: the HAL component's name and the Python of its HAL side
LinuxCncSection = LinuxCncOptions


class ControllerSection(Section):
    protocol: Protocol
    endpoint: Annotated[str, Field(min_length=1)]
    timeout_s: PositiveS = 0.5
    connect_timeout_s: PositiveS = 2.0
    backoff: BackoffSection = BackoffSection()
    security: SecuritySection | None = None
    s7: S7Section | None = None
    focas: FocasSection | None = None
    linuxcnc: LinuxCncSection | None = None

    @field_validator("endpoint")
    @classmethod
    def _endpoint(cls, v: str, info: ValidationInfo) -> str:
        """Checked as the driver checks it (`drivers.endpoint`), so that check
        refuses what run would; the message never echoes a user name or password."""
        why = url_credentials(v)
        if why is not None:
            raise ValueError(f"the endpoint {why} (set controller.security.username and "
                             f"password_file or password_env)")
        protocol = info.data.get("protocol")
        if protocol is not None:
            endpoint_of(protocol, v)
        return v


#: µm per unit of an input: one unit never warrants more than the largest output.limit_um
_WHY_DC_GAIN = ("one unit of an input never warrants more than the largest "
                "output.limit_um, 10 mm")


class ModelSection(Section):
    #: a model file (relative to the config file) or a bundled model name (e.g. "sp2")
    file: str | None = None
    #: inline terms, same format as a model file's [[terms]]
    terms: list[dict[str, Any]] | None = None
    name: str | None = None
    period_s: PeriodS | None = None
    #: a candidate model evaluated beside the live one, logged and recorded, never written
    shadow: str | None = None
    #: the reference state (°C per relative input channel: the temperatures at which the
    #: model's growth is zero, e.g. those of the calibration's start); overrides the model
    #: file's [reference]; neither: the temperatures at the first start (said in the log)
    reference: dict[str, float] | None = None
    #: refuse a model whose DC gain exceeds this (µm per unit of an input; models.sanity):
    #: at most 10 mm, the largest output.limit_um (one unit of an input never warrants more)
    max_dc_gain_um: Annotated[float, Field(gt=0.0),
                              *bounded(0.0, MAX_LIMIT_UM, " µm per unit", _WHY_DC_GAIN)
                              ] = 1000.0
    #: refuse a model whose slowest time constant exceeds this (models.sanity)
    max_time_constant_s: PositiveS = 7 * 86400.0

    @model_validator(mode="after")
    def _one_source(self) -> ModelSection:
        if (self.file is None) == (self.terms is None):
            raise ValueError("give either file = \"...\" or inline [[model.terms]], "
                             "exactly one")
        if self.file is not None and (self.name is not None or self.period_s is not None):
            raise ValueError("name and period_s belong to the model file, not beside file =")
        return self


#: [output] enabled = false (or no [output]): the stage's figures a recorder-only run
#: still steps its model's output through (nothing is written; `compd.core.cycle`)
_RECORDER_ONLY_OUTPUT: dict[str, Any] = {"offset": {}, "limit_um": MAX_LIMIT_UM,
                                         "slew_um_s": 1000.0, "readback": False}


class OutputSection(Section):
    #: false: recorder only (read, validate, record; nothing at all written to the
    #: controller: no offset, heartbeat or status); its addresses are then not needed
    enabled: bool = True
    offset: dict[str, Any]
    heartbeat: dict[str, Any] | None = None
    status: dict[str, Any] | None = None
    #: the axes word (`compd.core.output.AxesStatus`: each [output.axes] axis in force,
    #: alarm, holding, ramping, and a life bit), written beside the status word
    axes_status: dict[str, Any] | None = None
    unit: Literal["um", "mm", "nm", "inch", "count"] = "um"
    #: controller units per µm; derived from `unit` unless unit = "count"
    scale: float | None = None
    sign: Literal[1, -1] = 1
    #: at most 10 mm: a thermal offset beyond that is a broken model or machine
    limit_um: Annotated[float, Field(gt=0.0, le=MAX_LIMIT_UM, allow_inf_nan=False)]
    #: 0.001 µm/s (3.6 µm/h) ... 10 mm/s: the ramp-to-zero stays finite
    slew_um_s: Annotated[float, Field(ge=0.001, le=10000.0, allow_inf_nan=False)]
    deadband_um: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] = 0.0
    readback: bool = True
    #: the controller's state, read each cycle with the read-back (optional): a
    #: value 0 at `machine_on` or non-zero at `estop` means the controller takes no
    #: offset now (LinuxCNC zeroes its external offset at machine on): the offset is
    #: held, not written, and taken from the read-back when the machine is on again
    #: (compd.core.cycle, status bit CONTROLLER_OFF)
    machine_on: dict[str, Any] | None = None
    #: a value 0 means the machine is not homed (LinuxCNC takes no external offset
    #: then): held like machine off
    homed: dict[str, Any] | None = None
    estop: dict[str, Any] | None = None
    #: the controller permits the offset to change (optional; a PLC bit, an M-code, a
    #: HAL pin): while it reads 0 the offset in force is held and the model keeps
    #: stepping; unreadable counts as 0 (compd.core.cycle, cause waiting_for_permission)
    update_permitted: dict[str, Any] | None = None
    #: a re-zero request (optional; a PLC bit or an M-code pulse at tool touch-off): its
    #: rising edge takes the present prediction as the new zero (compd.core.cycle)
    rezero: dict[str, Any] | None = None
    #: [output.axes.<axis>]: per-axis compensation lines (`compd.config.axis_outputs`,
    #: checked by the loader)
    axes: dict[str, Any] | None = None

    @model_validator(mode="before")
    @classmethod
    def _recorder_only(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("enabled") is False:
            return {**_RECORDER_ONLY_OUTPUT, **data}
        return data

    @model_validator(mode="after")
    def _scale(self) -> OutputSection:
        derived = OUTPUT_UNITS[self.unit]
        if self.scale is None and derived is None:
            raise ValueError('unit = "count" needs scale (controller counts per µm)')
        if self.scale is not None and (not math.isfinite(self.scale) or self.scale == 0.0):
            raise ValueError("scale must be a finite non-zero number")
        if self.deadband_um >= self.limit_um:
            raise ValueError("deadband_um must be below limit_um")
        return self

    @property
    def units_per_um(self) -> float:
        if self.scale is not None:
            return self.scale
        derived = OUTPUT_UNITS[self.unit]
        return 1.0 if derived is None else derived


class FaultsSection(Section):
    hold_s: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] = 60.0
    shutdown: Literal["hold", "ramp_to_zero"] = "hold"
    checkpoint_max_age_s: PositiveS = 3600.0


class StateSection(Section):
    #: not given: $STATE_DIRECTORY when systemd sets it (StateDirectory=), else
    #: ``<config dir>/state`` (compd.config.loader)
    dir: LaxPath | None = None
    checkpoint_every: Annotated[int, Field(ge=1)] = 60


class RecorderSection(Section):
    enabled: bool = True
    path: LaxPath | None = None
    commit_every: Annotated[int, Field(ge=1)] = 10
    #: kept as a row count (one row a cycle: retention_days·86400/period_s rows);
    #: 0 keeps everything
    retention_days: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] = 30.0



#: what a channel may be called: an identifier, so that it is one column of a record
#: and never collides with the columns built from it (``valid.<channel>``)
CHANNEL_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")


class DaemonConfig(Section):
    machine: MachineSection = MachineSection()
    controller: ControllerSection
    channels: dict[str, ChannelSection]
    #: none: recorder only, which [output] must say (enabled = false, or no [output]);
    #: `compd.config.loader` refuses no model with an enabled output
    model: ModelSection | None = None
    #: none: recorder only (as enabled = false)
    output: OutputSection = OutputSection.model_validate({"enabled": False})
    faults: FaultsSection = FaultsSection()
    state: StateSection = StateSection()
    recorder: RecorderSection = RecorderSection()
    telemetry: TelemetrySection = TelemetrySection()
    faces: FacesSection = FacesSection()
    adaptation: AdaptationSection = AdaptationSection()

    @property
    def recorder_only(self) -> bool:
        """Read, validate and record; nothing written to the controller."""
        return not self.output.enabled

    @field_validator("channels")
    @classmethod
    def _some(cls, v: dict[str, ChannelSection]) -> dict[str, ChannelSection]:
        if not v:
            raise ValueError("at least one [channels.NAME] table is required")
        for name in v:
            if not CHANNEL_NAME.fullmatch(name):
                raise ValueError(
                    f"channel name {name[:80]!r}: letters, digits and underscores, starting "
                    "with a letter or underscore, at most 64 (it names a record's column, a "
                    "metric's label and an OPC UA node; a dot would read as another column's "
                    "prefix, e.g. valid.<channel> or x.state)")
        return v
