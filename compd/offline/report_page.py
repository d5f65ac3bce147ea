"""The calibration report's HTML: one self-contained page (style inline, the
figures inline SVG, no script, nothing fetched), every text from a file
escaped. Only this module writes markup; what it is given is plain text
(`Cell`), numbers, or SVG made by `compd.offline.report_svg`.
"""

from __future__ import annotations

import html
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

_STYLE = """
body{font-family:'DejaVu Sans',sans-serif;margin:0 auto;padding:1em 2em;max-width:1180px;
 color:#111;background:#fff;line-height:1.35}
h1{font-size:1.5em;margin:.4em 0}h2{font-size:1.2em;margin:1.4em 0 .4em 0;
 border-bottom:1px solid #bbb}h3{font-size:1.02em;margin:1em 0 .3em 0}
table{border-collapse:collapse;margin:.4em 0 .8em 0;font-size:.92em}
td,th{padding:.18em .7em;border-bottom:1px solid #ddd;text-align:left;vertical-align:top}
th{background:#f2f2f2}td.num,th.num{text-align:right;font-variant-numeric:tabular-nums}
.note{color:#444;font-size:.92em;margin:.3em 0}.missing{color:#8a5a00}
.chosen{font-weight:bold}.mono{font-family:'DejaVu Sans Mono',monospace;font-size:.88em;
 overflow-wrap:anywhere}
.name{font-family:'DejaVu Sans Mono',monospace;font-size:.88em;white-space:nowrap}
figure{margin:.4em 0 1.2em 0}figure svg{width:100%;height:auto;display:block}
figcaption{font-size:.9em;color:#333}
.swatch{display:inline-block;width:1.4em;height:.9em;vertical-align:middle;
 border:1px solid #999;margin:0 .3em 0 .8em}
"""


@dataclass(frozen=True)
class Cell:
    """A table cell: plain text (escaped when written), right-aligned when a
    number, in a class of the page's style."""

    text: str
    number: bool = False
    css: str = ""


def cell(value: object, fmt: str = "", css: str = "") -> Cell:
    """A cell for `value`: a float formatted with `fmt`, None as "—"."""
    if value is None:
        return Cell("—", True, css)
    if isinstance(value, bool):
        return Cell("yes" if value else "no", False, css)
    if isinstance(value, (int, float)):
        return Cell(format(value, fmt) if fmt else f"{value:g}", True, css)
    return Cell(str(value), False, css)


@dataclass
class Page:
    """The page's parts, in order, as markup built by the methods below."""

    title: str
    parts: list[str] = field(default_factory=list)

    def heading(self, text: str, level: int = 2, anchor: str = "") -> None:
        ident = f' id="{html.escape(anchor)}"' if anchor else ""
        self.parts.append(f"<h{level}{ident}>{html.escape(text)}</h{level}>")

    def note(self, text: str, css: str = "note") -> None:
        self.parts.append(f'<p class="{css}">{html.escape(text)}</p>')

    def table(self, header: Sequence[str], rows: Iterable[Sequence[Cell]],
              css: str = "") -> None:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join("<tr>" + "".join(_td(c) for c in row) + "</tr>" for row in rows)
        cls = f' class="{css}"' if css else ""
        self.parts.append(f"<table{cls}><thead><tr>{head}</tr></thead><tbody>{body}</tbody>"
                          "</table>")

    def figure(self, svg: str, caption: str) -> None:
        """`svg` from `report_svg.figure_svg` (made by this program, not read
        from a file), with an escaped caption."""
        self.parts.append(f"<figure>{svg}<figcaption>{html.escape(caption)}</figcaption>"
                          "</figure>")

    def legend(self, swatches: Sequence[tuple[str, str]], text: str) -> None:
        """A line of colour swatches (colour, name) after `text`."""
        marks = "".join(f'<span class="swatch" style="background:{html.escape(colour)}">'
                        f"</span>{html.escape(name)}" for colour, name in swatches)
        self.parts.append(f'<p class="note">{html.escape(text)}{marks}</p>')

    def render(self) -> str:
        return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
                '<meta name="viewport" content="width=device-width">'
                "<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; "
                "style-src 'unsafe-inline'; img-src data:\">"
                f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head>"
                "<body>\n" + "\n".join(self.parts) + "\n</body></html>\n")


def _td(c: Cell) -> str:
    classes = " ".join(x for x in ("num" if c.number else "", c.css) if x)
    cls = f' class="{classes}"' if classes else ""
    return f"<td{cls}>{html.escape(c.text)}</td>"
