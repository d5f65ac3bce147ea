"""How the cycle starts: from a fresh checkpoint, an old one, or nothing.

- fresh (saved less than checkpoint_max_age_s machine seconds ago, same
  model): the filters resume exactly where they were;
- too old, same model: the saved filter state is advanced over the time since
  it was saved with the first valid sample's inputs held (or, past
  `compd.core.modelstep.MAX_ADVANCE_STEPS`, the steady state of those inputs);
- another model, or unusable state: the references are kept (they describe
  the machine's reference state) and every term starts at the steady state
  matching the first valid sample: never from zero on a warm machine;
- none at all (first-ever start): the model's calibration reference
  (``[reference]`` / ``[model] reference``) and the steady state of the first
  valid sample; without one, the first sample's temperatures are the reference.

The config's model is a description: the cycle steps a copy of its own
(`compd.core.modelstep.ModelStepper`), so the same config starts a cycle
again (a fleet's restart, a reload) without the state of one before.

The ``model_initialised`` event says which (``mode``, ``reference``), and the
status page shows it. A re-zero (``zero`` in the checkpoint) is kept with the
same model, whatever the checkpoint's age.

In every case the output starts from the last offset the controller
confirmed (the checkpoint's `offset_um`; a write it refused, or one never
acknowledged, is not in it) and, with read-back, from what the controller
really holds.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from compd.config.loader import LoadedConfig
from compd.core.cycle import Cycle, CycleParams
from compd.core.events import Event, EventName
from compd.runtime.checkpoint import CHECKPOINT_NAME, CheckpointError, load_checkpoint
from compd.runtime.statedir import StateDir
from models.errors import ModelError


@dataclass
class Startup:
    cycle: Cycle
    mode: str  # restored | steady_state | first_start
    events: list[Event] = field(default_factory=list)


def checkpoint_path(cfg: LoadedConfig) -> Path:
    return cfg.state_dir / CHECKPOINT_NAME


def start_cycle(cfg: LoadedConfig, params: CycleParams, *,
                wall_s: float | None = None, directory: StateDir | None = None) -> Startup:
    """The cycle to run, and events saying how it was started. `directory`: the
    state directory as the daemon's lock holds it open (the checkpoint is read there)."""
    events: list[Event] = []
    path = checkpoint_path(cfg)
    state: dict[str, Any] | None
    try:
        state = load_checkpoint(path, directory=directory)
    except CheckpointError as exc:
        events.append(Event(EventName.CHECKPOINT_UNUSABLE, {"path": str(path), "reason": str(exc)}))
        state = None
    if state is None:
        return Startup(Cycle(params, cfg.model, cfg.shadow), "first_start", events)
    now = time.time() if wall_s is None else wall_s
    saved = state.get("saved_wall_s")
    age_s = (now - float(saved)) * cfg.raw.machine.time_scale \
        if isinstance(saved, int | float) else float("inf")
    same_model = state.get("model_sha256") == cfg.model_sha256
    fresh = 0.0 <= age_s <= cfg.raw.faults.checkpoint_max_age_s and same_model
    info = {"age_machine_s": round(age_s, 3) if age_s != float("inf") else None,
            "same_model": same_model, "offset_um": state.get("offset_um"),
            "sequence": state.get("sequence")}
    if fresh:
        try:
            cycle = Cycle.from_state(params, cfg.model, cfg.shadow, state, fresh=True,
                                     same_model=same_model)
        except (ModelError, TypeError, ValueError, KeyError) as exc:
            events.append(Event(EventName.CHECKPOINT_STATE_REFUSED, {"reason": str(exc)}))
        else:
            events.append(Event(EventName.CHECKPOINT_RESTORED, info))
            return Startup(cycle, "restored", events)
    try:
        cycle = Cycle.from_state(params, cfg.model, cfg.shadow, state, fresh=False,
                                 same_model=same_model,
                                 age_s=age_s if age_s != float("inf") else None)
    except (ModelError, TypeError, ValueError, KeyError) as exc:
        events.append(Event(EventName.CHECKPOINT_STATE_REFUSED, {"reason": str(exc)}))
        return Startup(Cycle(params, cfg.model, cfg.shadow), "first_start", events)
    events.append(Event(EventName.CHECKPOINT_TOO_OLD, info) if same_model
                  else Event(EventName.CHECKPOINT_OTHER_MODEL, info))
    return Startup(cycle, "steady_state", events)
