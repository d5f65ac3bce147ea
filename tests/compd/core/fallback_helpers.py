"""A model with fallbacks for the pure-cycle tests: SP2 (bearing + ambient) as a
model file with a ``[[fallback]]`` for each of its inputs."""

from __future__ import annotations

import tomllib

from models.compensation import CompensationModel
from models.modelfile import parse_model

#: SP2's two terms as the library has them (17.6 µm/K of bearing), under a model
#: table named for its fallbacks: the fallbacks are appended by each user
SP2_MAIN = """
[model]
name = "SP2 with fallbacks"
period_s = 1.0

[[terms]]
name = "spindle"
inputs = { bearing = 1.0 }
a = ["16.0005", "-15.9975", "0"]
b = ["1", "-0.99983", "0", "0"]

[[terms]]
name = "ambient"
inputs = { ambient = 1.0 }
a = ["-0.0251", "0.0251", "0"]
b = ["1", "-1.9985", "0.9985", "0"]
"""

SP2_WITH_FALLBACKS = SP2_MAIN + """
[[fallback]]
lost = "ambient"
model = { name = "without ambient", period_s = 1.0 }
[[fallback.terms]]
name = "spindle"
inputs = { bearing = 1.0 }
a = ["16.5", "-16.49"]
b = ["1", "-0.99983"]

[[fallback]]
lost = "bearing"
model = { name = "without bearing", period_s = 1.0 }
[[fallback.terms]]
name = "ambient"
inputs = { ambient = 1.0 }
a = ["0.05", "-0.0499"]
b = ["1", "-0.999"]
"""


def sp2_with_fallbacks(text: str = SP2_WITH_FALLBACKS) -> CompensationModel:
    return parse_model(tomllib.loads(text))
