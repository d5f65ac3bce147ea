"""One address of the daemon's config checked against its protocol's address
model (`drivers.protocols`), and pydantic's errors as one `ConfigError` naming
the dotted key, and the grid an address puts values on: what
`compd.config.loader` and the per-axis outputs (`compd.config.axis_outputs`) share."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ValidationError

from compd.config.suggest import errors_of
from compd.errors import ConfigError
from drivers.addresses import Address
from drivers.protocols import PROTOCOLS


def _loc(parts: tuple[int | str, ...]) -> str:
    out = ""
    for p in parts:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            out += ("." if out else "") + str(p)
    return out


def _reason(err: Any) -> str:
    kind = err.get("type", "")
    msg = str(err.get("msg", "invalid"))
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "missing":
        return "required key is missing"
    for prefix in ("Value error, ", "Assertion failed, "):
        if msg.startswith(prefix):
            msg = msg[len(prefix):]
    return msg


def config_error(exc: ValidationError, prefix: str = "",
                 root: type[BaseModel] | None = None) -> ConfigError:
    """Every pydantic error as one ConfigError, each with its dotted key path
    ("did you mean" for an unknown key when `root`, the validated model, is
    given); `key` and `reason` are the first error's. Tagged-union branch
    names (model class names) are dropped from the paths."""
    found = [(_loc(loc), why) for loc, why in errors_of(exc, root, _reason)]
    if prefix:
        found = [(f"{prefix}.{k}" if k else prefix, why) for k, why in found]
    if len(found) == 1:
        return ConfigError(*found[0])
    error = ConfigError("", f"{len(found)} mistakes: " + "; ".join(
        f"{k}: {why}" if k else why for k, why in found))
    error.key, error.reason = found[0]
    return error


def validate_address(protocol: str, doc: dict[str, Any], key: str) -> Address:
    spec = PROTOCOLS[protocol]
    if spec.default_kind is not None and "kind" not in doc:
        doc = {**doc, "kind": spec.default_kind}
    try:
        addr: Address = spec.address_adapter().validate_python(doc)
    except ValidationError as exc:
        other = _other_protocol(doc, protocol)
        if other:
            raise ConfigError(key, f"this looks like a {other} address but the controller "
                                   f"protocol is {protocol}") from None
        raise config_error(exc, key) from None
    return addr


def _other_protocol(doc: dict[str, Any], protocol: str) -> str | None:
    for name, spec in PROTOCOLS.items():
        if name == protocol:
            continue
        for cls in spec.address_types():
            try:
                cls.model_validate(doc)
            except ValidationError:
                continue
            return name
    return None


def quantum(addr: Address, per_unit: float = 1.0) -> float:
    """The step between values `addr` can hold, in the unit of which `per_unit`
    engineering units make one (0 for a float: no grid). Worked number: an int32
    at scale 0.1 holding µm steps by 0.1 µm."""
    enc = addr.encoding
    if enc is not None and enc.integer:
        return abs(float(getattr(addr, "scale", 1.0)) / per_unit)
    return 0.0


__all__ = ["config_error", "quantum", "validate_address"]
