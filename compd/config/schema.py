"""The daemon config's sections as pydantic models (extra keys refused).

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
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationInfo,
    field_validator,
    model_validator,
)

from compd.config.urls import url_credentials
from drivers.endpoint import endpoint_of, numeric_host_reason
from drivers.linuxcnc_options import LinuxCncOptions
from drivers.opcua_policy import OpcUaSecurityRules
from drivers.protocol_options import FocasOptions, S7Options
from drivers.protocols import ProtocolName

#: the protocol names, from the one registry (`drivers.protocols`)
Protocol = ProtocolName

#: channel units the daemon knows (what a value in a channel means)
UNITS: tuple[str, ...] = ("degC", "K", "rpm", "kW", "W", "um", "mm", "ratio", "percent",
                          "A", "Nm")

#: output units and their controller units per µm
OUTPUT_UNITS: dict[str, float | None] = {"um": 1.0, "mm": 1e-3, "nm": 1e3, "inch": 1.0 / 25400.0,
                                         "count": None}


#: channel units that are temperatures (their moves count for stuck_delta_k)
TEMPERATURE_UNITS: tuple[str, ...] = ("degC", "K")

#: stuck_delta_k of a temperature channel with stuck_after_s and no stuck_delta_k
DEFAULT_STUCK_DELTA_K = 2.0


class _Section(BaseModel):
    # strict: a TOML string is never silently read as a number or a boolean
    # ("100" for limit_um, "yes" for readback): wrong types are refused
    model_config = ConfigDict(extra="forbid", frozen=True, hide_input_in_errors=True,
                              strict=True)


#: a path given as a TOML string (strict mode alone would want a Path object)
LaxPath = Annotated[Path, Field(strict=False)]
StrictFloat = Annotated[float, Strict()]
PositiveS = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]


def _listen_host(v: str) -> str:
    """A host compd listens on, held to the endpoints' rule for numbers
    (`drivers.endpoint.numeric_host_reason`): ``0`` or ``0x0`` would listen on every
    interface, ``127.1`` where it reads as loopback; one spelling, the dotted quad."""
    why = numeric_host_reason(v)
    if why is not None:
        raise ValueError(why)
    return v


#: the address a face listens on: a name, an IPv6 address, or an IPv4 dotted quad
ListenHost = Annotated[str, Field(min_length=1), AfterValidator(_listen_host)]


#: a sample period within models.sanity's MIN_PERIOD_S ... MAX_PERIOD_S (10 ms ... 1 h)
PeriodS = Annotated[float, Field(ge=0.01, le=3600.0, allow_inf_nan=False)]


class MachineSection(_Section):
    name: str = "machine"
    period_s: PeriodS = 1.0
    #: machine seconds per real second: 1.0 in production, > 1 for the demo/bench
    time_scale: PositiveS = 1.0


#: the longest wait between reconnect attempts (real seconds): compensation
#: must resume within 10 s + 2·Ts after a lost link returns
MAX_BACKOFF_CAP_S = 10.0


class BackoffSection(_Section):
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

    model_config = _Section.model_config
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


class ControllerSection(_Section):
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


class ChannelSection(_Section):
    #: validated against the protocol's address model by `compd.config.loader`
    address: dict[str, Any]
    unit: str
    range: Annotated[tuple[StrictFloat, StrictFloat], Field(strict=False)]
    max_rate_per_s: PositiveS | None = None
    stale_after_s: PositiveS | None = None
    stuck_after_s: PositiveS | None = None
    #: stuck when unchanged while another temperature channel moved by more than
    #: this (K) since it last changed; default DEFAULT_STUCK_DELTA_K for a
    #: temperature channel with stuck_after_s; inf turns it off. Not for a
    #: sensor that may rightly stay put while the machine heats (the hall's
    #: ambient): see compd.core.validation
    stuck_delta_k: Annotated[float, Field(gt=0.0)] | None = None

    @field_validator("stuck_delta_k")
    @classmethod
    def _stuck_delta(cls, v: float | None, info: ValidationInfo) -> float | None:
        if v is not None and info.data.get("unit", TEMPERATURE_UNITS[0]) not in TEMPERATURE_UNITS:
            raise ValueError("applies to temperature channels only (unit degC or K): "
                             "it compares how far other temperatures moved")
        return v

    @property
    def temperature(self) -> bool:
        return self.unit in TEMPERATURE_UNITS

    @property
    def effective_stuck_delta_k(self) -> float | None:
        """The heat criterion's threshold in K, None when off."""
        v = self.stuck_delta_k
        if v is None and self.stuck_after_s is not None and self.temperature:
            v = DEFAULT_STUCK_DELTA_K
        return v if v is not None and math.isfinite(v) else None

    @field_validator("unit")
    @classmethod
    def _unit(cls, v: str) -> str:
        if v not in UNITS:
            raise ValueError(f"unknown unit {v!r}; known: {', '.join(UNITS)}")
        return v

    @field_validator("range")
    @classmethod
    def _range(cls, v: tuple[float, float]) -> tuple[float, float]:
        lo, hi = v
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ValueError("bounds must be finite numbers")
        if not lo < hi:
            raise ValueError("lower bound must be below upper bound")
        return v


def _bounded(lo: float, hi: float, unit: str, why: str) -> tuple[Any, AfterValidator]:
    """A finite number's metadata: its Field (its range in the JSON schema, `compd
    schema`; `why` as the description) and a validator refusing a value outside
    [lo, hi] with the range and the reason."""
    def check(v: float) -> float:
        if not lo <= v <= hi:
            raise ValueError(f"must be within {lo:g} ... {hi:g}{unit}, got {v:g} ({why})")
        return v

    return (Field(allow_inf_nan=False, description=why,
                  json_schema_extra={"minimum": lo, "maximum": hi}),
            AfterValidator(check))


#: [adaptation]'s physical bounds. The estimator (models.adaptation.DOMAIN) stays finite
#: far beyond them; these are what a machine tool makes sensible, and a value outside is a
#: typo or an attack, refused by name at check, run and reload alike. The reasons:
_WHY_BIAS_RW = ("the model's error wanders some 0.1 ... 2 µm/√h on a machine; beyond "
                "100 µm/√h is more than a machine's whole thermal growth in an hour")
_WHY_PROBE_NOISE = ("a touch probe repeats within 1 µm, a tool setter within a few: no "
                    "probe repeats better than 10 nm, and one scattering over 100 µm "
                    "measures nothing a thermal correction can use")
_WHY_GATE = ("below 1 σ the gate refuses a third of the good probes; no good probe "
             "reaches 10 σ (p ≈ 1e-23), a wider gate only lets chips and wrong tools in")
_WHY_CORRECTION = ("1 nm ... 10 mm and at most output.limit_um: the output stage clamps "
                   "there, a larger bound only hides a runaway estimate")
_WHY_GAIN_RW = ("a term's gain that may wander by its whole size within an hour is not "
                "a slow drift but a wrong model")
_WHY_MAX_GAIN = ("a relative gain correction of ±1 removes or doubles a term: beyond "
                 "that the model is wrong, recalibrate")
#: the largest output.limit_um (10 mm): no correction, step or gain goes beyond it
MAX_LIMIT_UM = 10000.0
#: the bounds (low, high) of [adaptation]'s estimator settings, by name: what `compd check`
#: and `run` hold the config's settings and a model file's [adaptation] table to
#: (`learnt_bounds`)
ADAPTATION_BOUNDS: dict[str, tuple[float, float]] = {
    "bias_rw_um_per_sqrt_h": (0.0, 100.0),
    "probe_noise_um": (0.01, 100.0),
    "gate_sigma": (1.0, 10.0),
    "max_step_um": (0.001, MAX_LIMIT_UM),
    "max_total_um": (0.001, MAX_LIMIT_UM),
    "gain_rw_per_sqrt_h": (0.0, 1.0),
    "max_gain": (0.0, 1.0),
    "score_window": (0, 100),
    "reacquire_after": (0, 100),
}
_B = ADAPTATION_BOUNDS
BiasRw = Annotated[float, *_bounded(*_B["bias_rw_um_per_sqrt_h"], " µm/√h", _WHY_BIAS_RW)]
ProbeNoise = Annotated[float, *_bounded(*_B["probe_noise_um"], " µm", _WHY_PROBE_NOISE)]
GateSigma = Annotated[float, *_bounded(*_B["gate_sigma"], " σ", _WHY_GATE)]
Correction = Annotated[float, *_bounded(*_B["max_step_um"], " µm", _WHY_CORRECTION)]
GainRw = Annotated[float, *_bounded(*_B["gain_rw_per_sqrt_h"], " per √h", _WHY_GAIN_RW)]
MaxGain = Annotated[float, *_bounded(*_B["max_gain"], "", _WHY_MAX_GAIN)]
_WHY_SCORE_WINDOW = ("probes the estimator scores itself over: 0 never stands down; beyond "
                     "100 probes a machine's error has long changed, the score only lags")
ScoreWindow = Annotated[int, *_bounded(*_B["score_window"], " probes", _WHY_SCORE_WINDOW)]
_WHY_REACQUIRE = ("refusals in a row, agreeing in direction, after which the estimator "
                  "re-acquires: 0 never; beyond 100 probes a real change has long been "
                  "missed")
ReacquireAfter = Annotated[int, *_bounded(*_B["reacquire_after"], " probes", _WHY_REACQUIRE)]
_WHY_GUARD = ("probes in a row showing the model worse than none before the alarm: 0 no "
              "guard; beyond 100 probes a wrong model would run for days")
GuardWindow = Annotated[int, *_bounded(0, 100, " probes", _WHY_GUARD)]
#: µm per unit of an input: one unit never warrants more than the largest output.limit_um
_WHY_DC_GAIN = ("one unit of an input never warrants more than the largest "
                "output.limit_um, 10 mm")


class ModelSection(_Section):
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
                              *_bounded(0.0, MAX_LIMIT_UM, " µm per unit", _WHY_DC_GAIN)
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


class OutputSection(_Section):
    #: false: recorder only (read, validate, record; nothing at all written to the
    #: controller: no offset, heartbeat or status); its addresses are then not needed
    enabled: bool = True
    offset: dict[str, Any]
    heartbeat: dict[str, Any] | None = None
    status: dict[str, Any] | None = None
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


class FaultsSection(_Section):
    hold_s: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] = 60.0
    shutdown: Literal["hold", "ramp_to_zero"] = "hold"
    checkpoint_max_age_s: PositiveS = 3600.0


class StateSection(_Section):
    #: not given: $STATE_DIRECTORY when systemd sets it (StateDirectory=), else
    #: ``<config dir>/state`` (compd.config.loader)
    dir: LaxPath | None = None
    checkpoint_every: Annotated[int, Field(ge=1)] = 60


class RecorderSection(_Section):
    enabled: bool = True
    path: LaxPath | None = None
    commit_every: Annotated[int, Field(ge=1)] = 10
    #: kept as a row count (one row a cycle: retention_days·86400/period_s rows);
    #: 0 keeps everything
    retention_days: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] = 30.0


class TelemetrySection(_Section):
    metrics_port: Annotated[int, Field(ge=1, le=65535)] | None = None
    #: the address /metrics listens on: loopback by default; "0.0.0.0" or "::" in a
    #: container whose port is published, or for a Prometheus on another host
    metrics_host: ListenHost = "127.0.0.1"
    #: the HTTP server's bounds (/metrics and [faces.http]): open connections at most
    #: (beyond: the one waiting longest for a request is closed), seconds for a whole
    #: request head, seconds a kept-alive connection may sit idle
    metrics_max_connections: Annotated[int, Field(ge=1, le=1000)] = 64
    metrics_header_timeout_s: Annotated[float, Field(gt=0.0, le=300.0,
                                                     allow_inf_nan=False)] = 5.0
    metrics_idle_timeout_s: Annotated[float, Field(gt=0.0, le=3600.0,
                                                   allow_inf_nan=False)] = 30.0
    #: the least level of the protocol libraries' own loggers (asyncua, snap7,
    #: pymodbus); "default": WARNING, pymodbus CRITICAL (it logs every failed
    #: frame as an ERROR hex dump that our read_failed/write_failed already tell)
    library_log_level: Literal["default", "debug", "info", "warning", "error",
                               "critical"] = "default"
    log_format: Literal["auto", "json", "console"] = "auto"
    log_level: Literal["debug", "info", "warning", "error"] = "info"


class HttpFaceSection(_Section):
    """``[faces.http]``: the operator status page (``/`` and ``/status.json``) served
    beside ``/metrics`` (``[telemetry] metrics_port`` and ``metrics_host``)."""

    enabled: bool = False
    #: hours of offset and model output the page plots (from the recorder)
    history_h: Annotated[float, Field(gt=0.0, le=168.0, allow_inf_nan=False)] = 4.0
    #: how often the page fetches /status.json (real seconds)
    refresh_s: Annotated[float, Field(ge=1.0, le=3600.0, allow_inf_nan=False)] = 5.0


class OpcUaFaceSection(_Section):
    """``[faces.opcua]``: compd's own OPC UA server (`compd.faces.opcua_face`):
    read-only for every client; SetHold only for `operator`."""

    enabled: bool = False
    host: ListenHost = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 4841
    policy: Literal["Basic256Sha256", "Aes128_Sha256_RsaOaep", "Aes256_Sha256_RsaPss",
                    "None"] = "Basic256Sha256"
    #: the server's application instance certificate and key (PEM or DER)
    certificate: LaxPath | None = None
    private_key: LaxPath | None = None
    #: must be true for policy "None", and only on a loopback host
    insecure: bool = False
    #: clients may read without a user name (with policy None: always)
    anonymous_read: bool = False
    #: the one user who may call SetHold (and read)
    operator: Annotated[str, Field(min_length=1)] | None = None
    #: the operator's password: a file (relative: $CREDENTIALS_DIRECTORY or the
    #: config's folder), never the config itself
    operator_password_file: LaxPath | None = None
    #: TCP connections served at once (fewer when RLIMIT_NOFILE leaves less); one
    #: more is closed at once
    max_connections: Annotated[int, Field(ge=1, le=1000)] = 32
    #: sessions at once; one more is refused (BadTooManySessions)
    max_sessions: Annotated[int, Field(ge=1, le=1000)] = 16
    #: sessions anonymous readers never take (with an operator): the operator's
    reserved_sessions: Annotated[int, Field(ge=1, le=1000)] = 1
    #: a connection without a session this long after it was accepted is closed
    handshake_timeout_s: Annotated[float, Field(gt=0.0, le=300.0, allow_inf_nan=False)] = 10.0

    @model_validator(mode="before")
    @classmethod
    def _no_inline_password(cls, data: Any) -> Any:
        if isinstance(data, dict) and any("password" in k and not k.endswith("_file")
                                          for k in data):
            raise ValueError("a password is never written in the config: use "
                             "operator_password_file")
        return data

    @model_validator(mode="after")
    def _secure_by_default(self) -> OpcUaFaceSection:
        if not self.enabled:
            return self
        if self.policy == "None":
            if not self.insecure:
                raise ValueError("policy None sends everything readable and unauthenticated: "
                                 "set insecure = true to accept that (loopback only)")
            if not _loopback(self.host):
                raise ValueError(f"policy None is only for a loopback host, not {self.host!r}: "
                                 "use Basic256Sha256 with a certificate")
        elif self.certificate is None or self.private_key is None:
            raise ValueError(f"policy {self.policy} needs certificate and private_key "
                             "(the server's application instance certificate)")
        if (self.operator is None) != (self.operator_password_file is None):
            raise ValueError("operator and operator_password_file go together")
        if self.policy == "None" and self.operator is not None:
            raise ValueError("an operator password with policy None would cross the wire "
                             "readable: use a secure policy for SetHold")
        # the face's anonymous share (compd.faces.opcua_limits.Guard.anonymous_limit)
        share = min(self.max_sessions - self.reserved_sessions, self.max_connections // 2)
        if self.anonymous_read and self.operator is not None and share < 1:
            raise ValueError(
                f"reserved_sessions = {self.reserved_sessions} with max_sessions = "
                f"{self.max_sessions} and max_connections = {self.max_connections} leaves "
                "anonymous readers no session (they take at most max_sessions - "
                "reserved_sessions, and half the connections): raise the limits, or turn "
                "anonymous_read off")
        return self


def _loopback(host: str) -> bool:
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class FacesSection(_Section):
    """``[faces]``: what compd shows the shop floor besides logs and metrics."""

    http: HttpFaceSection = HttpFaceSection()
    opcua: OpcUaFaceSection = OpcUaFaceSection()
class AdaptationSection(_Section):
    """``[adaptation]``: learn from the machine's probe measurements
    (`compd.core.adaptation`; the estimator's settings default to
    `models.adaptation.AdaptationParams`). Every numeric setting has a physical
    bound (above); `max_step_um` and `max_total_um` are also at most
    `output.limit_um` (the loader)."""

    enabled: bool = False
    #: "shadow": the estimator's correction is estimated and recorded, not applied;
    #: "apply": added to the model output (the guard acts in both: guard_action)
    mode: Literal["shadow", "apply"] = "shadow"
    #: what the measuring cycle leaves: "residual" (the probe on a compensating
    #: machine: growth minus the offset in force) or "displacement"
    measures: Literal["residual", "displacement"] = "residual"
    #: controller address of the measured Z deviation (µm)
    probe_value: dict[str, Any] | None = None
    #: controller address of a counter (or timestamp) that changes with each measurement
    probe_counter: dict[str, Any] | None = None
    bias_rw_um_per_sqrt_h: BiasRw | None = None
    probe_noise_um: ProbeNoise | None = None
    gate_sigma: GateSigma | None = None
    max_step_um: Correction | None = None
    max_total_um: Correction | None = None
    gains: bool | None = None
    gain_rw_per_sqrt_h: GainRw | None = None
    max_gain: MaxGain | None = None
    #: accepted probes the estimator keeps score over; it stands down (applies nothing)
    #: while adapting loses to the plain model over them (models.adaptation)
    score_window: ScoreWindow | None = None
    #: gate refusals in a row agreeing in direction after which the estimator
    #: re-acquires (a real change, within max_total_um); 0: never
    reacquire_after: ReacquireAfter | None = None
    #: the guard "no model worse than none" (compd.core.adaptation): this many probes
    #: in a row each showing the compensation making the error larger than none would
    #: (by more than twice probe_noise_um) are an alarm and a fault (hold, then ramp
    #: to zero per [faults]) until another model is loaded; 0: no guard
    guard_window: GuardWindow = 3
    #: what the guard's verdict does, in either mode (it judges the compensation in
    #: force, which "shadow" does not change): "fault" holds, then ramps to zero;
    #: "report" raises the event, the status page's line and the metric only
    guard_action: Literal["fault", "report"] = "fault"

    def estimator_settings(self) -> dict[str, Any]:
        """The estimator settings given (the others keep their defaults)."""
        names = ("bias_rw_um_per_sqrt_h", "probe_noise_um", "gate_sigma", "max_step_um",
                 "max_total_um", "gains", "gain_rw_per_sqrt_h", "max_gain", "score_window",
                 "reacquire_after")
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}


def learnt_bounds() -> dict[str, tuple[float, float]]:
    """(low, high) of every numeric setting a model file's [adaptation] table may hold, as
    `compd check` and `run` hold it there: [adaptation]'s bound where the section has the
    setting (the loader validates the table's keys as the section's), else the
    estimator's domain (`models.adaptation.DOMAIN`, checked by `models.modelfile`)."""
    from models.adaptation import DOMAIN

    return {name: ADAPTATION_BOUNDS.get(name, domain) for name, domain in DOMAIN.items()}


class DaemonConfig(_Section):
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
        return v
