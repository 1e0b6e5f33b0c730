"""Pieces the HTML report's modules share: escaping, numbers and tables as HTML, a
matplotlib figure as an embedded PNG, and the located places a diagnosis document names."""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _num(x: Any, digits: int = 4) -> str:
    """A number for a table cell (``-`` for none / non-finite)."""
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int | np.integer):
        return str(int(x))
    try:
        v = float(x)
    except (TypeError, ValueError):
        return _e(x)
    return f"{v:.{digits}g}" if math.isfinite(v) else "-"


def _table(header: Sequence[str], rows: Iterable[Sequence[str]], cls: str = "") -> str:
    """An HTML table; cells are already HTML."""
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def _param_cell(p: Mapping[str, Any]) -> str:
    """``value ± se unit``; arrays as their size and largest magnitude, full in details."""
    v, se, unit = p.get("value"), p.get("se"), p.get("unit", "")
    if v is None or np.ndim(v) == 0:
        s = _num(v, 6)
        if se is not None:
            s += f" ± {_num(se, 3)}"
        return f"{s} {_e(unit)}"
    va = np.asarray(v, dtype=float)
    sa = np.asarray(se, dtype=float) if se is not None else None
    shape = "×".join(str(n) for n in va.shape)
    i = int(np.nanargmax(np.abs(va))) if va.size else 0
    s = f"{shape} values, largest {_num(va.flat[i], 4)}"
    if sa is not None and sa.shape == va.shape and va.size:
        s += f" ± {_num(sa.flat[i], 3)}"
    s += f" {_e(unit)}"
    flat = [
        f"{_num(a, 5)} ± {_num(b, 3)}" if sa is not None and sa.shape == va.shape else _num(a, 5)
        for a, b in zip(va.ravel(), sa.ravel() if sa is not None else va.ravel())
    ]
    return f"{s}<details><summary>all</summary>{_e(', '.join(flat))}</details>"


def _where_text(w: Mapping[str, Any] | None) -> str:
    if not w:
        return "-"
    parts = []
    for key, lab in (
        ("orders", "orders"),
        ("frequencies_hz", "Hz"),
        ("heads", "heads"),
        ("runs", "runs"),
        ("times_s", "t (s)"),
    ):
        vals = w.get(key) or []
        if vals:
            parts.append(f"{lab}: " + ", ".join(_num(v, 5) for v in vals[:8]))
    return _e("; ".join(parts)) or "-"


def _png(fig: Any) -> str:
    """A matplotlib figure as an ``<img>`` with a base64 PNG ``data:`` URI."""
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=90)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="figure" src="data:image/png;base64,{data}">'


def _figure() -> Any:
    from matplotlib.figure import Figure

    return Figure


def _located(doc: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """Every ``where`` the document names: findings before, unexplained, effects'."""
    out = []
    for f in list(doc.get("findings_before") or []) + list(doc.get("unexplained") or []):
        if isinstance(f.get("where"), Mapping):
            out.append(f["where"])
    for e in doc.get("effects") or []:
        if isinstance(e.get("where"), Mapping):
            out.append(e["where"])
    return out


def _located_orders(doc: Mapping[str, Any]) -> list[float]:
    orders = {round(float(o), 3) for w in _located(doc) for o in (w.get("orders") or []) if o}
    return sorted(orders)
