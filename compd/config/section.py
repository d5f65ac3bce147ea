"""What every section of the daemon config is built from: the strict, frozen, closed
pydantic base (`Section`), the common field types, and `bounded` for a number whose range
and reason are shown by `compd schema` and named when a value is refused."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict

from drivers.endpoint import numeric_host_reason


class Section(BaseModel):
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



def bounded(lo: float, hi: float, unit: str, why: str) -> tuple[Any, AfterValidator]:
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

#: the largest output.limit_um (10 mm): no correction, step or gain goes beyond it
MAX_LIMIT_UM = 10000.0
