"""`compd schema`: print the daemon config's JSON Schema.

Generated from the pydantic models of `compd.config.schema`, so it says what
the loader accepts key by key (types, ranges, unknown keys refused). Editors
validate TOML against it as it is typed: Even Better TOML / Taplo read a
``#:schema ./compd.schema.json`` line at the top of the file. The checks that
span sections (addresses against the protocol, the model's stability and
period) stay `compd check`'s.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

HELP = "print the daemon config's JSON Schema (for editors that validate TOML as it is typed)"

SCHEMA_ID = "https://compd.invalid/schema/config.json"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--indent", type=int, choices=range(0, 9), default=2, metavar="N",
                        help="indent the JSON by N spaces, 0 for one line (default 2)")


def config_schema() -> dict[str, Any]:
    from compd import __version__
    from compd.config.schema import DaemonConfig

    schema = DaemonConfig.model_json_schema(mode="validation")
    return {**schema, "$schema": "https://json-schema.org/draft/2020-12/schema",
            "$id": SCHEMA_ID, "title": f"compd {__version__} daemon config",
            "description": "One TOML file: compd run CONFIG (docs/operation.md)."}


def run(args: argparse.Namespace) -> int:
    print(json.dumps(config_schema(), indent=args.indent or None, ensure_ascii=False))
    return 0
