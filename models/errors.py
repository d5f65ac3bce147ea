"""The errors of the numeric core.

`ModelError` is the base of what `models` raises on purpose. It knows nothing
of the daemon above it: compd's own root error is `compd.errors.CompdError`,
and compd catches `ModelError` where it reads a model (`compd check`, the
config loader, the commands).
"""

from __future__ import annotations


class ModelError(ValueError):
    """A model is malformed or unsafe: bad coefficients, an unstable pole,
    an unknown channel. The message names the term and the reason."""
