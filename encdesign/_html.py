"""HTML pieces shared by the reports: escaping, numbers, tables, a status badge and the frame
of a result's rich display in Jupyter (``_repr_html_``).

The diagnosis report (``encdesign/diagnose/engine/_html.py``) builds its tables from these;
the design results (:class:`~encdesign.design.Solution`, ...) and
:class:`~encdesign.diagnose.Diagnosis` render in a notebook through :func:`result_html`. Every
value goes through :func:`escape` or :func:`num`: a file name, an effect's explanation or a
driver's message cannot inject markup. Base module: imports nothing of encdesign.
"""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

CSS = """
.encdesign-result table{border-collapse:collapse;margin:.4em 0;font-size:.9em}
.encdesign-result td,.encdesign-result th{border:1px solid #ccc;padding:.2em .5em;
text-align:left;vertical-align:top}
.encdesign-result th{background:#f3f3f3}
.encdesign-result td.num{text-align:right;font-variant-numeric:tabular-nums}
.encdesign-result .badge,.encdesign-result .verdict{display:inline-block;padding:.1em .6em;
border-radius:.3em;color:#fff;font-weight:600}
.encdesign-result .ok,.encdesign-result .v-consistent{background:#2a7d2a}
.encdesign-result .not-ok,.encdesign-result .v-unexplained{background:#a11}
.encdesign-result .v-missing_physics{background:#b5651d}
.encdesign-result .small{font-size:.85em;color:#555}
"""
"""Styles of :func:`result_html`, every rule scoped to its ``div`` (a notebook's own styles
are left alone)."""

MAX_ITEMS = 8
"""Elements of an array shown in a cell (the rest counted)."""


def escape(x: object) -> str:
    """``x`` as HTML text (quotes escaped too: safe inside an attribute)."""
    return html.escape(str(x), quote=True)


def num(x: Any, digits: int = 4) -> str:
    """A number for a table cell (``-`` for none / non-finite, ``yes`` / ``no`` for a bool)."""
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int | np.integer):
        return str(int(x))
    try:
        v = float(x)
    except (TypeError, ValueError):
        return escape(x)
    return f"{v:.{digits}g}" if math.isfinite(v) else "-"


def array_cell(a: ArrayLike, digits: int = 6) -> str:
    """A scalar, or the first :data:`MAX_ITEMS` elements of an array and how many there are."""
    v = np.asarray(a)
    if v.ndim == 0:
        return num(v.item(), digits)
    flat = v.ravel()
    shown = ", ".join(num(x, digits) for x in flat[:MAX_ITEMS].tolist())
    more = f", … ({flat.size} values)" if flat.size > MAX_ITEMS else ""
    return f"[{shown}{more}]"


def table(header: Sequence[str], rows: Iterable[Sequence[str]], cls: str = "") -> str:
    """An HTML table; the header is text (escaped here), the cells are already HTML."""
    head = "".join(f"<th>{escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def status_badge(status: object, ok: bool) -> str:
    """The status as a green (an answer) or red (not) badge."""
    return f'<span class="badge {"ok" if ok else "not-ok"}">{escape(status)}</span>'


def result_html(
    title: str,
    headline: str,
    fields: Iterable[tuple[str, str]] = (),
    sections: Iterable[str] = (),
) -> str:
    """A result for Jupyter: a scoped style, a title (text), a headline (HTML: the status or
    verdict), a table of ``(name, HTML value)`` fields, then any further HTML sections."""
    rows = [[escape(k), v] for k, v in fields]
    parts = [
        '<div class="encdesign-result">',
        f"<style>{CSS}</style>",
        f"<p><b>{escape(title)}</b> · {headline}</p>",
    ]
    if rows:
        parts.append(table(["", "value"], rows, "fields"))
    parts += list(sections)
    parts.append("</div>")
    return "\n".join(parts)
