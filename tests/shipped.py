"""The files the packages ship, where the imported packages keep them: tests
read the examples, the model library and the drive maps here (never through
the repository's folders), so that a run against an installed wheel checks the
wheel's own files and fails on one the package left out."""

from __future__ import annotations

from pathlib import Path

import compd
import models
from drivers.sim.drive_map import MAPS_DIR

#: the folder that holds compd/, drivers/ and models/ as imported: the checkout
#: in an editable install, site-packages for a wheel (tests that read the source)
PACKAGES_ROOT = Path(compd.__file__).resolve().parents[1]
#: the complete configs, one per protocol (compd/examples/*.toml)
EXAMPLES = Path(compd.__file__).resolve().parent / "examples"
#: the model library `compd check NAME` and `--model NAME` read (models/library/*.toml)
LIBRARY = Path(models.__file__).resolve().parent / "library"
#: the HIL bench's drive maps, `compd sim --drive`'s default (drivers/sim/maps/*.toml)
MAPS = MAPS_DIR
