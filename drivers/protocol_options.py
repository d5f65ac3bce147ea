"""The option tables of the protocols that have some (pydantic only).

Each is the ``[controller.<protocol>]`` table of the daemon's config and,
for a HIL bench, what a drive map's ``[driver]`` may set; `driver_options`
gives the keyword options of the protocol's driver. OPC UA's table is its
security (`drivers.opcua_policy`). Found from `drivers.protocols`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, field_validator


class _Options(BaseModel):
    # strict, as every config section: a "1" for a slot is a mistake to report
    model_config = ConfigDict(extra="forbid", frozen=True, hide_input_in_errors=True,
                              strict=True)

    def driver_options(self) -> dict[str, Any]:
        """Keyword options for the protocol's driver."""
        return self.model_dump(exclude_none=True)


class S7Options(_Options):
    rack: Annotated[int, Field(ge=0, le=7)] = 0
    slot: Annotated[int, Field(ge=0, le=31)] = 1


class FocasOptions(_Options):
    library_path: Annotated[Path, Field(strict=False)]
    library_sha256: str | None = None

    @field_validator("library_path")
    @classmethod
    def _absolute(cls, v: Path) -> Path:
        if not v.is_absolute():
            raise ValueError("must be an absolute path (a relative library path loads "
                             "whatever the working directory holds)")
        return v

    @field_validator("library_sha256")
    @classmethod
    def _hex(cls, v: str | None) -> str | None:
        if v is not None and (len(v) != 64 or any(c not in "0123456789abcdefABCDEF" for c in v)):
            raise ValueError("must be 64 hex digits (sha256 of the library file)")
        return v.lower() if v is not None else None

    def driver_options(self) -> dict[str, Any]:
        return {"library_path": str(self.library_path), "library_sha256": self.library_sha256}


__all__ = ["FocasOptions", "S7Options"]
