"""One self-contained HTML page: sections of text, tables and PNG figures, nothing fetched.

A report is read in a browser, offline, mailed as one file, opened years later: every figure
is a PNG embedded as a ``data:`` URI, the style is inline CSS, and there is no JavaScript. The
figures are drawn with matplotlib's object API on an Agg canvas (:func:`new_figure`), never
through ``pyplot``: no global backend is switched (a user's notebook keeps its own), and
matplotlib is imported only when a report is made (``jaxgeo --help`` and every command without
``--report`` start without it).
"""

from __future__ import annotations

import base64
import dataclasses
import datetime
import html
import io
import os
import pathlib
from collections.abc import Sequence
from typing import Any

from ..io.internal import atomic_write_text

SCREEN_WIDTH_PX = 900
"""Width of every figure (px): one column of a laptop's screen, readable without zooming."""
DPI = 100
"""Figure resolution (dots per inch of matplotlib's size): ``SCREEN_WIDTH_PX / DPI`` inches."""

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;
max-width:960px;padding:16px 24px;color:#1b1b1b;background:#fff;line-height:1.45}
h1{font-size:1.6em;margin:.3em 0}h2{font-size:1.25em;border-bottom:1px solid #ccc;
padding-bottom:.2em;margin-top:1.6em}h3{font-size:1.05em;margin-top:1.2em}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}
figure{margin:.8em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.9em;color:#444}.meta{color:#555;font-size:.9em}
.warn{background:#fff4e5;border-left:4px solid #e67e00;padding:6px 10px}
"""


def new_figure(height_px: int = 450, width_px: int = SCREEN_WIDTH_PX):
    """A matplotlib ``Figure`` of ``width_px`` x ``height_px`` on an Agg canvas (no pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_px / DPI, height_px / DPI), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig) -> bytes:
    """``fig`` as PNG bytes (its own size and DPI)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


@dataclasses.dataclass
class Page:
    """An HTML page assembled in order: :meth:`section`, :meth:`text`, :meth:`table`,
    :meth:`figure`; :meth:`write` it atomically. ``title``: the page's heading; ``meta``:
    lines under it (the command, the inputs)."""

    title: str
    meta: Sequence[str] = ()
    parts: list[str] = dataclasses.field(default_factory=list)

    def section(self, heading: str, level: int = 2) -> None:
        self.parts.append(f"<h{level}>{html.escape(heading)}</h{level}>")

    def text(self, paragraph: str, warn: bool = False) -> None:
        cls = ' class="warn"' if warn else ""
        self.parts.append(f"<p{cls}>{html.escape(paragraph)}</p>")

    def table(self, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        """A table; numbers formatted with :func:`cell` (``None``/NaN: a dash)."""
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(cell(v))}</td>" for v in row) + "</tr>"
            for row in rows
        )
        self.parts.append(f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")

    def figure(self, fig, caption: str, alt: str | None = None) -> None:
        """``fig`` embedded as a PNG ``data:`` URI with its caption (the figure is closed)."""
        data = base64.b64encode(png_bytes(fig)).decode("ascii")
        fig.clear()
        alt = html.escape(alt or caption, quote=True)
        self.parts.append(
            f'<figure><img alt="{alt}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )

    def html(self) -> str:
        made = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
        meta = "".join(f'<p class="meta">{html.escape(m)}</p>' for m in self.meta)
        from .. import __version__

        return (
            '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            '<meta name="viewport" content="width=device-width,initial-scale=1">'
            f"<title>{html.escape(self.title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{html.escape(self.title)}</h1>{meta}"
            f'<p class="meta">jaxgeo {html.escape(__version__)}, {made}</p>'
            + "\n".join(self.parts)
            + "\n</body></html>\n"
        )

    def write(self, path: str | os.PathLike, overwrite: bool = False) -> pathlib.Path:
        """The page written to ``path`` atomically (an existing file only with ``overwrite``:
        ``FileExistsError`` naming it otherwise)."""
        return atomic_write_text(path, self.html(), overwrite=overwrite)


def cell(value: Any) -> str:
    """A table cell: floats to 4 significant digits, ``None`` and NaN as a dash."""
    if value is None:
        return "–"
    if isinstance(value, float):
        return "–" if value != value else f"{value:.4g}"
    return str(value)


def report_beside(output: str | os.PathLike) -> pathlib.Path:
    """Where the report of a raster product goes: beside it, ``<output stem>.report.html``
    (``dsm.tif`` -> ``dsm.report.html``): several products of one job can share a folder."""
    output = pathlib.Path(output)
    return output.with_name(f"{output.stem}.report.html")
