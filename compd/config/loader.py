"""Load and validate the daemon config: one TOML file, every error a
`ConfigError` naming the dotted key path and the reason (exit 78).

`load_config(path)` reads the file, validates the sections
(`compd.config.schema`), then the checks that span sections: the controller
timeout against the period, every address against the protocol's address
model and against the others (`compd.config.overlaps`: no written address
overlaps another), the model (file or inline terms: stable, its channels
configured, its period equal to the machine's) and the shadow model. Nothing
here connects to anything. ``[adaptation]``'s checks are `compd.config.adaptation_check`,
the state directory and password files `compd.config.paths`.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from pydantic import ValidationError

from compd.config.adaptation_check import PROBE_NAMES, adaptation_settings
from compd.config.address_check import config_error
from compd.config.address_check import quantum as _quantum_um
from compd.config.address_check import validate_address as _validate_address
from compd.config.axis_outputs import (
    MODEL_KEYS,
    AxisModels,
    AxisOutputSet,
    PositionChannel,
    parse_axis_outputs,
)
from compd.config.model_section import RECORDER_MODEL_NAME, model_sha256, recorder_model
from compd.config.model_section import check_limits as _check_limits
from compd.config.model_section import check_section_limits as _check_model
from compd.config.model_section import model_from_ref as _load_model
from compd.config.model_section import section_model as _section_model
from compd.config.model_section import set_reference as _set_reference
from compd.config.output_range import HEARTBEAT_MAX, STATUS_MAX, check_outputs
from compd.config.overlaps import check_overlaps
from compd.config.paths import credential_path, read_password, resolve_state_dir
from compd.config.schema import (
    ControllerSection,
    DaemonConfig,
    ModelSection,
)
from compd.core.adaptation import AdaptationSettings
from compd.errors import ConfigError
from compd.infiles import MAX_CONFIG_BYTES, InputError, read_toml_document
from drivers.addresses import Address
from drivers.linuxcnc_options import LinuxCncOptions, long_hal_name
from drivers.protocols import PROTOCOLS
from models.compensation import CompensationModel

#: the names other modules import from here that live in the modules beside it
__all__ = ["PROBE_NAMES", "RECORDER_MODEL_NAME", "credential_path", "model_sha256",
           "read_password", "recorder_model", "resolve_state_dir"]

#: output names as the driver sees them
OUTPUT_NAMES: tuple[str, ...] = ("offset", "heartbeat", "status", "axes_status")
#: the controller's state read beside the channels ([output] machine_on, estop, homed,
#: update_permitted, rezero)
STATE_NAMES: tuple[str, ...] = ("machine_on", "estop", "homed", "update_permitted", "rezero")


@dataclass(frozen=True)
class LoadedConfig:
    """A validated config with everything resolved (addresses typed, model built):
    a plain value, shared and reused as it is (a reload makes a new one). Its
    `model` and `shadow` are descriptions: the cycle steps copies of its own
    (`compd.core.modelstep.ModelStepper`), never these."""

    path: Path
    raw: DaemonConfig
    #: these four are read-only views (a copy made here): every sink and face reads
    #: the one config, none may change what another reads
    channels: Mapping[str, Address]
    outputs: Mapping[str, Address]
    model: CompensationModel
    shadow: CompensationModel | None
    state_dir: Path
    recorder_path: Path | None
    config_sha256: str
    model_sha256: str
    #: smallest step the offset address can hold, in µm (read-back tolerance)
    offset_quantum_um: float
    #: [adaptation] when enabled: the cycle's settings and the probe's two addresses
    #: (read under PROBE_NAMES beside the channels)
    adaptation: AdaptationSettings | None = None
    probes: Mapping[str, Address] = field(default_factory=dict)
    #: the controller's state ([output] machine_on, estop, homed), read under STATE_NAMES
    states: Mapping[str, Address] = field(default_factory=dict)
    #: [output.axes.<axis>]: the per-axis compensation lines and their models (their
    #: parameters are in `outputs` too, by `drivers.temp_comp.output_name`); None: none
    axes: AxisOutputSet | None = None

    def __post_init__(self) -> None:
        for name in ("channels", "outputs", "probes", "states"):
            object.__setattr__(self, name, MappingProxyType(dict(getattr(self, name))))

    @property
    def recorder_only(self) -> bool:
        """[output] enabled = false (or no [output]): nothing is written to the controller."""
        return self.raw.recorder_only

    @property
    def model_given(self) -> bool:
        """The config names a model; False: `model` is `recorder_model`'s stand-in."""
        return self.raw.model is not None

    @property
    def period_s(self) -> float:
        return self.raw.machine.period_s

    @property
    def real_period_s(self) -> float:
        return self.raw.machine.period_s / self.raw.machine.time_scale


def with_model(cfg: LoadedConfig, model: CompensationModel) -> LoadedConfig:
    """`cfg` with `model` in place of its own (`compd replay MODEL --config CFG`), checked
    as the loader checks the config's model (its channels among cfg's, stable, its
    period cfg's); ConfigError with the key ``model`` and the reason."""
    m = cfg.raw.model
    if m is not None:
        limits = {"max_dc_gain_um": m.max_dc_gain_um,
                  "max_time_constant_s": m.max_time_constant_s}
    else:
        limits = {name: ModelSection.model_fields[name].default
                  for name in ("max_dc_gain_um", "max_time_constant_s")}
    _check_limits(model, cfg.channels, cfg.period_s, "model", **limits)
    return dataclasses.replace(cfg, model=model, model_sha256=model_sha256(model))


def _check_hal_names(options: LinuxCncOptions, channels: dict[str, Address],
                     probes: dict[str, Address], outputs: dict[str, Address]) -> None:
    """Every pin ``<component>.<pin>`` compd makes fits HAL's names (47 characters),
    also as a restarted HAL side names it; else HAL refuses it at every start."""
    for where, table in (("channels.{}.address.pin", channels),
                         ("adaptation.{}", probes), ("output.{}", outputs)):
        long = long_hal_name(options.component, table)
        if long is not None:
            raise ConfigError(where.format(long[0]), long[1])


def _check_protocol_sections(ctl: ControllerSection) -> None:
    """Each [controller.<section>] only with its protocol; a required one given."""
    for spec in PROTOCOLS.values():
        if spec.section is None:
            continue
        given = getattr(ctl, spec.section) is not None
        if given and ctl.protocol != spec.name:
            raise ConfigError(f"controller.{spec.section}",
                              f"[controller.{spec.section}] is for protocol {spec.name}, "
                              f"not {ctl.protocol}")
        if not given and ctl.protocol == spec.name and spec.section_required:
            raise ConfigError(f"controller.{spec.section}",
                              f"protocol {spec.name} needs [controller.{spec.section}] "
                              f"({spec.section_required})")


def parse_config(doc: dict[str, Any], path: Path, text: bytes = b"") -> LoadedConfig:
    """Validate an already parsed TOML document (`path` anchors relative paths)."""
    try:
        raw = DaemonConfig.model_validate(doc)
    except ValidationError as exc:
        raise config_error(exc, root=DaemonConfig) from None
    base = path.parent
    machine, ctl = raw.machine, raw.controller
    limit_s = 0.5 * machine.period_s / machine.time_scale
    if ctl.timeout_s > limit_s:
        raise ConfigError("controller.timeout_s",
                          f"{ctl.timeout_s:g} s is more than half the real sample period "
                          f"({limit_s:g} s = 0.5·period_s/time_scale)")
    _check_protocol_sections(ctl)
    if ctl.security is not None and ctl.security.password_file is not None:
        ctl_pf = credential_path(ctl.security.password_file, base)
        if not ctl_pf.is_file():
            raise ConfigError("controller.security.password_file", f"no such file: {ctl_pf}")

    channels = {name: _validate_address(ctl.protocol, ch.address, f"channels.{name}.address")
                for name, ch in raw.channels.items()}
    outputs, states = _outputs(raw, channels)
    m = raw.model
    if m is None and not raw.recorder_only:
        raise ConfigError("model", "required key is missing (a run without a model only "
                          "records: say so with [output] enabled = false)")
    if m is None:  # recorder only
        model = recorder_model(channels, machine.period_s)
    else:
        model = _section_model(m, base, channels, machine.period_s, "model")
    shadow = None
    if m is not None and m.shadow is not None:
        shadow = _load_model(m.shadow, base, "model.shadow")
        _check_model(shadow, channels, machine.period_s, "model.shadow", m)
    if m is not None and m.reference is not None and shadow is not None:
        _set_reference(shadow, m.reference)

    state_dir = resolve_state_dir(raw.state.dir, base)
    if state_dir.exists() and not state_dir.is_dir():
        raise ConfigError("state.dir", f"{state_dir} exists and is not a directory")
    recorder_path: Path | None = None
    if raw.recorder.enabled:
        rp = raw.recorder.path or Path("samples.sqlite")
        recorder_path = rp if rp.is_absolute() else (
            base / rp if raw.recorder.path is not None else state_dir / rp)
        if recorder_path.is_dir():
            raise ConfigError("recorder.path", f"{recorder_path} is a directory, not a file")
    adaptation, probes = adaptation_settings(raw, channels, model.adaptation)
    check_overlaps(outputs, channels, probes, states)
    axes = _axes(raw, base, channels, outputs, probes, states)
    if axes is None and "axes_status" in outputs:
        raise ConfigError("output.axes_status", "the axes word needs [output.axes.<axis>] "
                          "(it says which axes are in force)")
    if axes is not None:
        outputs = {**outputs, **axes.driver_outputs()}
    if ctl.protocol == "linuxcnc":
        _check_hal_names(ctl.linuxcnc or LinuxCncOptions(), channels, probes, outputs)
    return LoadedConfig(
        path=path, raw=raw, channels=channels, outputs=outputs, model=model, shadow=shadow,
        state_dir=state_dir, recorder_path=recorder_path,
        config_sha256=hashlib.sha256(text).hexdigest(), model_sha256=model_sha256(model),
        offset_quantum_um=(_quantum_um(outputs["offset"], raw.output.units_per_um)
                           if "offset" in outputs else 0.0),
        adaptation=adaptation, probes=probes, states=states, axes=axes)


def _axes(raw: DaemonConfig, base: Path, channels: dict[str, Address],
          outputs: Mapping[str, Address], probes: Mapping[str, Address],
          states: Mapping[str, Address]) -> AxisOutputSet | None:
    """``[output.axes.<axis>]``: each axis's addresses and limits
    (`compd.config.axis_outputs`), its models built and checked as ``[model]``'s
    are (`_section_model`), a rate for each parameter a model drives."""
    table = raw.output.axes
    if raw.recorder_only or not table:
        return None
    others = {**{f"output.{n}": a for n, a in outputs.items()},
              **{f"channels.{n}.address": a for n, a in channels.items()},
              **{f"adaptation.{n}": a for n, a in probes.items()},
              **{f"output.{n}": a for n, a in states.items()}}
    positions = {n: PositionChannel((ch.range[0], ch.range[1]), ch.stale_after_s)
                 for n, ch in raw.channels.items() if ch.unit == "mm"}
    found = parse_axis_outputs(raw.controller.protocol, table, others=others,
                               positions=positions)
    models: dict[str, AxisModels] = {}
    for axis in found.axes:
        at, doc, stage = f"output.axes.{axis}", table[axis], found.stages[axis]
        if "model" not in doc:
            raise ConfigError(f"{at}.model", "required key is missing (the value's model: "
                              "file = \"...\" or inline terms, as [model])")
        built = [_axis_model(doc[k], base, channels, raw.machine.period_s, f"{at}.{k}")
                 if k in doc else None for k in MODEL_KEYS]
        value, slope = built
        assert value is not None  # checked above
        if stage.slew_um_s is None:
            raise ConfigError(f"{at}.slew_um_s", "required key is missing (the value's "
                              "rate limit, µm/s)")
        if slope is not None and stage.slope_slew_um_m_s is None:
            raise ConfigError(f"{at}.slope_slew_um_m_s", "required key is missing with "
                              "slope_model (the slope's rate limit, µm/m per s)")
        models[axis] = AxisModels(value, slope, model_sha256(value),
                                  model_sha256(slope) if slope is not None else "")
    return dataclasses.replace(found, models=models)


def _axis_model(doc: Any, base: Path, channels: dict[str, Address], period_s: float,
                key: str) -> CompensationModel:
    """One axis model: a table of the ``[model]`` form (no shadow)."""
    if not isinstance(doc, Mapping):
        raise ConfigError(key, "must be a table, as [model] (file = \"...\" or terms)")
    if "shadow" in doc:
        raise ConfigError(f"{key}.shadow", "an axis model has no shadow")
    try:
        section = ModelSection.model_validate(dict(doc))
    except ValidationError as exc:
        raise config_error(exc, key) from None
    return _section_model(section, base, channels, period_s, key)


def _outputs(raw: DaemonConfig, channels: dict[str, Address]
             ) -> tuple[dict[str, Address], dict[str, Address]]:
    """The written outputs and the controller's state read beside the channels, each
    address checked; recorder only: none of either (its [output] addresses unused)."""
    out, protocol = raw.output, raw.controller.protocol
    if raw.recorder_only:
        return {}, {}
    outputs: dict[str, Address] = {"offset": _validate_address(protocol, out.offset,
                                                               "output.offset")}
    for name in ("heartbeat", "status", "axes_status"):
        doc_addr = getattr(out, name)
        if doc_addr is not None:
            outputs[name] = _validate_address(protocol, doc_addr, f"output.{name}")
    check_outputs(outputs, limit_um=out.limit_um, units_per_um=out.units_per_um,
                  sign=out.sign, heartbeat_max=HEARTBEAT_MAX, status_max=STATUS_MAX)
    clash = sorted(set(channels) & set(OUTPUT_NAMES))
    if clash:
        raise ConfigError(f"channels.{clash[0]}", "this name is reserved for an output")
    states: dict[str, Address] = {}
    for name in STATE_NAMES:
        doc_addr = getattr(out, name)
        if doc_addr is not None:
            if name in channels:
                raise ConfigError(f"channels.{name}", "this name is reserved for the "
                                  f"controller's state (output.{name})")
            states[name] = _validate_address(protocol, doc_addr, f"output.{name}")
    return outputs, states


def load_config(path: str | Path) -> LoadedConfig:
    """Read and validate a daemon config file; raises ConfigError."""
    p = Path(path)
    try:
        text, doc = read_toml_document(p, "config file", MAX_CONFIG_BYTES)
    except InputError as exc:
        raise ConfigError("", str(exc)) from None
    return parse_config(doc, p.resolve(), text)
