"""A matplotlib figure as an SVG element to inline in an HTML page.

Text stays text (``svg.fonttype = none``: searchable, copyable, and a browser
can measure it); matplotlib writes it XML-escaped, so a name from a file
cannot become markup. The XML prolog and DOCTYPE are cut (invalid inside
HTML), so is the metadata block, and every ``id`` and reference to one is prefixed per figure: two
figures inlined in one page would otherwise share the ids of their clip
paths.
"""

from __future__ import annotations

import io
import re

from matplotlib import rc_context
from matplotlib.figure import Figure

_ID = re.compile(r'(\bid=")([^"]+)(")')
_REF = re.compile(r'(url\(#|xlink:href="#|href="#)([^)"]+)')


def figure_svg(fig: Figure, prefix: str) -> str:
    """`fig` as one ``<svg>`` element (its own size and viewBox: a page's CSS
    may scale it), its ids prefixed with `prefix`."""
    buf = io.BytesIO()
    with rc_context({"svg.fonttype": "none", "svg.hashsalt": prefix}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    text = buf.getvalue().decode("utf-8")
    text = text[text.index("<svg"):]
    text = re.sub(r"\s*<metadata>.*?</metadata>", "", text, count=1, flags=re.S)
    text = _ID.sub(lambda m: f"{m.group(1)}{prefix}-{m.group(2)}{m.group(3)}", text)
    text = _REF.sub(lambda m: f"{m.group(1)}{prefix}-{m.group(2)}", text)
    return text.strip()
