"""SIGHUP reload: the config and model read and validated again, then swapped
in between two cycles.

`prepare` (in a worker thread, while the loop keeps cycling) loads the file
with the same loader as `compd run`; a file that does not validate raises
ConfigError and the daemon keeps the old config (``reload_failed`` with the
key and the reason). `handover` builds the cycle that continues the old one:

- the output stage starts from what the controller is known to hold (the last
  confirmed offset; with read-back, what it reads) and slews to the new
  model's value at the (new) slew limit: never a jump;
- the same model (same sha256): the filters carry over exactly (the old
  cycle's state, imported into the new cycle's own copy of the model);
- another model: the references are kept and every term starts at the steady
  state matching the first valid sample (today's temperatures), as after a
  restart with an old checkpoint;
- the sequence and heartbeat continue; a permanent write refusal is kept
  while the output addresses are the same.

The fault policy (its hold timer) carries over, and so do the channel
validator's stale/stuck timers while the channels' limits are unchanged: a
reload never resets a fault's hold time (`Cycle.carry_over`).

What cannot change without a restart is refused with the key, like a
validation error: the state directory (it holds the lock),
machine.period_s / machine.time_scale (the models are discretised at the
period, and the machine clock runs on the schedule), the OPC UA face, and
output.offset moved to other memory of the same controller (the old address
would keep the last offset for ever under a live heartbeat: `_offset_stays`).

A reload that lowers output.limit_um below the offset compd last wrote ramps
that offset into the new limit at the slew limit (`compd.core.output`), the
read-back of it being compd's own, not a foreign value beyond the limit.
"""

from __future__ import annotations

from dataclasses import dataclass

from compd.config.loader import LoadedConfig, load_config
from compd.config.schema import TelemetrySection
from compd.core.cycle import Cycle, CycleParams
from compd.errors import ConfigError


@dataclass(frozen=True)
class Changes:
    """What differs between the running config and the reloaded one."""

    model: bool
    #: endpoint, protocol options or channel/output addresses: a new driver
    controller: bool
    outputs: bool
    recorder: bool
    metrics: bool
    #: the config's keys whose values differ ("output.slew_um_s"), and "model" when
    #: only the model file's content did
    keys: tuple[str, ...] = ()

    def names(self) -> list[str]:
        """What the reload restarts or rebuilds (model filters, driver, outputs…)."""
        return [k for k, v in vars(self).items() if v is True]


def changed_keys(old: object, new: object, prefix: str = "") -> list[str]:
    """The dotted keys whose values differ between two dumped config documents."""
    if isinstance(old, dict) and isinstance(new, dict):
        out: list[str] = []
        for key in sorted(set(old) | set(new), key=str):
            out += changed_keys(old.get(key), new.get(key), f"{prefix}{key}.")
        return out
    return [] if old == new else [prefix.rstrip(".")]


def prepare(old: LoadedConfig) -> tuple[LoadedConfig, Changes]:
    """Load and validate `old.path` again; raises ConfigError (the daemon keeps
    `old`)."""
    new = load_config(old.path)
    if new.state_dir != old.state_dir:
        raise ConfigError("state.dir", f"changed from {old.state_dir} to {new.state_dir}: "
                          "the state directory holds the lock, restart compd to move it")
    for key in ("period_s", "time_scale"):
        was, now = getattr(old.raw.machine, key), getattr(new.raw.machine, key)
        if was != now:
            raise ConfigError(f"machine.{key}", f"changed from {was:g} to {now:g}: "
                              "restart compd to change the sample clock")
    if new.raw.faces.opcua != old.raw.faces.opcua:
        raise ConfigError("faces.opcua", "changed: the OPC UA face's server and its "
                          "security are set at start; restart compd to change them")
    if new.recorder_only != old.recorder_only:
        raise ConfigError("output.enabled", (
            "changed between recorder only and writing: what compd writes to the "
            "controller is decided at start; restart compd to change it"))
    if not new.recorder_only:
        _offset_stays(old, new)
    return new, diff(old, new)


def _offset_stays(old: LoadedConfig, new: LoadedConfig) -> None:
    """Refuse a reload that moves the offset to other memory of the same
    controller: the old address would keep the last offset for ever while the
    heartbeat and status word stay live, so a PLC still reading it would apply a
    stale offset from a healthy-looking compd. Another endpoint is another
    controller (a replaced PLC): the old one's heartbeat stops, which its PLC
    sees as compd gone."""
    if new.raw.controller.endpoint != old.raw.controller.endpoint:
        return
    was, now = old.outputs["offset"], new.outputs["offset"]
    was_at, now_at = was.footprint(), now.footprint()
    moved = was_at != now_at if was_at is not None or now_at is not None else was != now
    if moved:
        raise ConfigError("output.offset", (
            f"moved from {was.describe()} to {now.describe()}: a reload would leave "
            f"{was.describe()} holding the last offset while the heartbeat and status "
            "stay live; restart compd to move it (with [faults] shutdown = "
            '"ramp_to_zero" the stop ramps the old address to 0 first)'))


def diff(old: LoadedConfig, new: LoadedConfig) -> Changes:
    o, n = old.raw, new.raw
    shadow_old = old.shadow.name if old.shadow else None
    shadow_new = new.shadow.name if new.shadow else None
    keys = changed_keys(o.model_dump(), n.model_dump())
    if old.model_sha256 != new.model_sha256 and not any(k.startswith("model") for k in keys):
        keys.append("model")  # the same file name, other content
    return Changes(
        keys=tuple(keys),
        model=old.model_sha256 != new.model_sha256 or shadow_old != shadow_new,
        controller=(o.controller != n.controller or old.channels != new.channels
                    or old.outputs != new.outputs or old.states != new.states),
        outputs=old.outputs != new.outputs,
        recorder=(old.recorder_path, o.recorder) != (new.recorder_path, n.recorder),
        metrics=(_served(o.telemetry), o.faces.http) != (_served(n.telemetry), n.faces.http))


def _served(t: TelemetrySection) -> tuple[object, ...]:
    """What the metrics server is started with: a change restarts it."""
    return (t.metrics_port, t.metrics_host, t.metrics_max_connections,
            t.metrics_header_timeout_s, t.metrics_idle_timeout_s)


def handover(old: Cycle, new_cfg: LoadedConfig, params: CycleParams,
             changes: Changes) -> Cycle:
    """The cycle continuing `old` under the new config (see the module docstring)."""
    state = old.export_state()
    if state["offset_um"] is None and not params.readback:
        # nothing confirmed and nothing to read back: start from where the stage is
        state["offset_um"] = old.output.current_um
    cycle = Cycle.from_state(params, new_cfg.model, new_cfg.shadow, state,
                             fresh=not changes.model)
    cycle.carry_over(old, same_outputs=not changes.outputs)
    return cycle
