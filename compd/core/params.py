"""What a cycle is built with (`CycleParams`, frozen) and how the config gives
it (`params_from_config`): period, hold time, the output stage's limits, the
channels' validation limits, the output names, adaptation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from compd.core.adaptation import AdaptationSettings
from compd.core.axes import AxisParams
from compd.core.validation import ChannelLimits

if TYPE_CHECKING:
    from compd.config.loader import LoadedConfig


@dataclass(frozen=True)
class CycleParams:
    period_s: float
    hold_s: float
    limit_um: float
    slew_um_s: float
    channels: dict[str, ChannelLimits]
    deadband_um: float = 0.0
    sign: int = 1
    units_per_um: float = 1.0
    readback: bool = True
    #: a float offset address's (an integer one: half a count, `OutputStage`)
    readback_tolerance_um: float = 0.01
    #: the offset address's resolution in µm (integer types), 0 for floats
    offset_quantum_um: float = 0.0
    time_scale: float = 1.0
    offset_name: str = "offset"
    heartbeat_name: str | None = "heartbeat"
    status_name: str | None = "status"
    #: the axes word (`compd.core.output.AxesStatus`), None: not written
    axes_status_name: str | None = None
    #: probe-assisted adaptation (`compd.core.adaptation`), None when off
    adaptation: AdaptationSettings | None = None
    #: read, validate, record; write nothing at all (`compd.core.cycle`)
    recorder_only: bool = False
    #: the model's output goes into the record (False: a recorder-only stand-in's)
    record_model: bool = True
    #: [output.axes.<axis>]: the per-axis compensation lines (`compd.core.axes`)
    axes: tuple[AxisParams, ...] = ()


def params_from_config(cfg: LoadedConfig, *, dry_run: bool = False) -> CycleParams:
    raw = cfg.raw
    out = raw.output
    limits = {n: ChannelLimits(ch.range[0], ch.range[1], ch.max_rate_per_s, ch.stale_after_s,
                               ch.stuck_after_s, stuck_delta_k=ch.effective_stuck_delta_k,
                               temperature=ch.temperature)
              for n, ch in raw.channels.items()}
    return CycleParams(
        period_s=raw.machine.period_s, hold_s=raw.faults.hold_s, limit_um=out.limit_um,
        slew_um_s=out.slew_um_s, channels=limits, deadband_um=out.deadband_um, sign=out.sign,
        units_per_um=out.units_per_um,
        readback=out.readback and not dry_run and not cfg.recorder_only,
        # float32 rounding; an integer address: half a count (OutputStage.observe)
        readback_tolerance_um=0.01,
        offset_quantum_um=cfg.offset_quantum_um,
        time_scale=raw.machine.time_scale,
        heartbeat_name="heartbeat" if "heartbeat" in cfg.outputs else None,
        status_name="status" if "status" in cfg.outputs else None,
        axes_status_name="axes_status" if "axes_status" in cfg.outputs else None,
        adaptation=cfg.adaptation, recorder_only=cfg.recorder_only,
        record_model=cfg.model_given, axes=axis_params(cfg))


def axis_params(cfg: LoadedConfig) -> tuple[AxisParams, ...]:
    """Each ``[output.axes.<axis>]`` of `cfg` as the cycle takes it."""
    found = cfg.axes
    if found is None:
        return ()
    out = []
    for axis in found.axes:
        lim, stage, models = found.limits(axis), found.stages[axis], found.models[axis]
        vq, sq = found.quanta.get(axis, (0.0, 0.0))
        at = found.positional.get(axis)
        out.append(AxisParams(
            axis=axis, value_model=models.value, slope_model=models.slope,
            reference_mm=found.reference_mm[axis], value_limit_um=lim.value_limit_um,
            slope_limit_um_m=lim.slope_limit_um_m,
            value_slew_um_s=stage.slew_um_s if stage.slew_um_s is not None else 1.0,
            slope_slew_um_m_s=(stage.slope_slew_um_m_s
                               if stage.slope_slew_um_m_s is not None else 1.0),
            value_deadband_um=stage.deadband_um, slope_deadband_um_m=stage.slope_deadband_um_m,
            value_quantum_um=vq, slope_quantum_um_m=sq,
            reference_quantum_mm=found.reference_quantum_mm.get(axis, 0.0),
            value_sha256=models.value_sha256, slope_sha256=models.slope_sha256,
            position=at.position if at is not None else None,
            offset_limit_um=at.offset_limit_um if at is not None else 0.0,
            offset_quantum_um=at.offset_quantum_um if at is not None else 0.0,
            value_only=axis == "tool"))
    return tuple(out)
