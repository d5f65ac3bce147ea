"""``[adaptation]`` checked against the rest of the config: both probe addresses valid for
the protocol and apart from the channels, the estimator's settings (the config's over
the model file's learnt ones) each within the config's bounds and output.limit_um."""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from compd.config.address_check import config_error
from compd.config.address_check import validate_address as _validate_address
from compd.config.schema import AdaptationSection, DaemonConfig
from compd.core.adaptation import AdaptationSettings
from compd.errors import ConfigError
from drivers.addresses import Address
from models.adaptation import AdaptationParams, mark_unproven, with_probe_noise

#: the names the probe's addresses are read under (beside the channels)
PROBE_NAMES = ("probe_value", "probe_counter")


def adaptation_settings(raw: DaemonConfig, channels: dict[str, Address],
                learnt: dict[str, Any] | None = None
                ) -> tuple[AdaptationSettings | None, dict[str, Address]]:
    """[adaptation] checked: both probe addresses, the estimator's settings: the
    config's over the model file's [adaptation] table (`learnt`: what `compd fit
    --adaptation` learnt), each within the config's bounds."""
    a = raw.adaptation
    if not a.enabled:
        return None, {}
    probes: dict[str, Address] = {}
    for key, name in zip(("probe_value", "probe_counter"), PROBE_NAMES, strict=True):
        doc = getattr(a, key)
        if doc is None:
            raise ConfigError(f"adaptation.{key}", "required when adaptation is enabled: the "
                              "controller address the measuring cycle writes")
        if name in channels:
            raise ConfigError(f"channels.{name}", "this name is reserved for the probe")
        probes[name] = _validate_address(raw.controller.protocol, doc, f"adaptation.{key}")
    limit = raw.output.limit_um
    table = learnt_settings(learnt or {}, limit)
    for key in ("max_step_um", "max_total_um"):
        value = getattr(a, key)
        if value is not None and value > limit:
            raise ConfigError(f"adaptation.{key}", f"{value:g} µm is beyond output.limit_um "
                              f"({limit:g} µm): the output stage clamps there, a larger "
                              "bound only hides a runaway estimate")
    try:
        # settings not learnt for this model start stood down (models.adaptation.mark_unproven)
        given = a.estimator_settings()
        if "probe_noise_um" in given:  # the machine's probe, not the record's noise (the
            # probe spacing taken as compd fit's default lag: the config does not say it)
            table = with_probe_noise(table, given["probe_noise_um"])
        params = AdaptationParams(**{**mark_unproven(table), **given})
    except (ValueError, TypeError) as exc:  # "name: why; …" (AdaptationParams.problems)
        first = str(exc).split("; ")[0]
        name, _, why = first.partition(": ")
        raise ConfigError(f"adaptation.{name}" if why else "adaptation", why or first) from None
    return AdaptationSettings(mode=a.mode, measures=a.measures, params=params,
                              guard_window=a.guard_window,
                              guard_action=a.guard_action), probes


def learnt_settings(table: dict[str, Any], limit_um: float) -> dict[str, Any]:
    """The model file's [adaptation] table held to the config's bounds: a key the config
    has is validated as the config would (ConfigError naming it), and the step and total
    bounds are at most output.limit_um (the output stage clamps there)."""
    table = {k: min(v, limit_um) if k in ("max_step_um", "max_total_um") else v
             for k, v in table.items()}  # numbers: models.modelfile checked them
    keys = set(AdaptationSection.model_fields) & set(table)
    try:
        AdaptationSection.model_validate({k: table[k] for k in keys})
    except ValidationError as exc:
        raise config_error(exc, prefix="model [adaptation]") from None
    return table
