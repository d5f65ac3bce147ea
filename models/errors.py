"""The project's root error and the errors of the numeric core.

`CompdError` lives here, in the lowest layer, so that `drivers` and `compd`
can derive from it without `models` importing anything above itself.
"""

from __future__ import annotations


class CompdError(Exception):
    """Root of every error compd raises on purpose."""


class ModelError(CompdError, ValueError):
    """A model is malformed or unsafe: bad coefficients, an unstable pole,
    an unknown channel. The message names the term and the reason."""
