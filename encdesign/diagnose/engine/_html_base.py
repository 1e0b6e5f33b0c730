"""Pieces the HTML report's modules share: escaping, numbers and tables as HTML (from the
package's HTML pieces, ``encdesign/_html.py``, which the results' notebook display uses too), a
matplotlib figure as an embedded PNG, and the located places a diagnosis document names."""

from __future__ import annotations

import base64
import io
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from ..._html import escape as _e
from ..._html import num as _num
from ..._html import table as _table  # noqa: F401 (the report's modules import it from here)
from ._located import describe

if TYPE_CHECKING:
    from matplotlib.figure import Figure


class ReportRows(TypedDict):
    """The per-row arrays of a diagnosis that the report draws (:func:`._html.report_inputs`),
    over the recording's rows in the finder's order."""

    tau: np.ndarray
    """(n,) time with the runs end to end (s)."""
    t: np.ndarray
    """(n,) time within the run (s)."""
    run: np.ndarray
    """(n,) the run as the document names it."""
    keep: np.ndarray
    """(n,) bool: the rows the fits used."""
    theta: np.ndarray | None
    """(n,) the shaft angle (rad), ``None`` when the recording has none."""
    base_resid: np.ndarray
    """(n, C) residual of the base model (unit of the document)."""
    final_resid: np.ndarray
    """(n, C) residual of the final model."""
    effects: dict[str, np.ndarray]
    """``{name: (n, C)}`` each named effect's own fitted contribution (may be empty)."""
    channels: list[str]
    """The C channel names."""


def _param_cell(p: Mapping[str, Any]) -> str:
    """``value ± se unit``; arrays as their size and largest magnitude, full in details; a
    time with its run and interval on the recording's own ``t`` (issue 44 C)."""
    v, se, unit = p.get("value"), p.get("se"), p.get("unit", "")
    if v is None or np.ndim(v) == 0:
        s = _num(v, 6)
        if se is not None:
            s += f" ± {_num(se, 3)}"
        s = f"{s} {_e(unit)}"
        if "interval_s" in p and v is not None:
            s += "<br>" + _located_cell({"t_s": float(v), **p})
        return s
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


def _located_cell(lt: Mapping[str, Any] | None) -> str:
    """A located time with its run and interval on the recording's own ``t``."""
    if not lt:
        return ""
    return _e(f"{describe(dict(lt))} ({lt.get('clock', 'the recording' + chr(39) + 's t')})")


def _located_intervals(doc: Mapping[str, Any]) -> list[tuple[int, float, int, float]]:
    """``(run, t, run, t)`` of the ends of every located time's interval: the findings',
    the unexplained structure's, and the effects' parameters that are times."""
    out = []
    items = list(doc.get("findings_before") or []) + list(doc.get("unexplained") or [])
    lts = [f["located_time"] for f in items if isinstance(f.get("located_time"), Mapping)]
    for e in doc.get("effects") or []:
        lts += [p for p in (e.get("params") or {}).values() if "interval_s" in p]
    for lt in lts:
        (t0, t1), (r0, r1) = lt["interval_s"], lt["interval_runs"]
        if (r0, t0, r1, t1) not in [(a, b, c, d) for a, b, c, d in out]:
            out.append((r0, float(t0), r1, float(t1)))
    return out


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


def _png(fig: Figure) -> str:
    """A matplotlib figure as an ``<img>`` with a base64 PNG ``data:`` URI."""
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=90)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="figure" src="data:image/png;base64,{data}">'


def _figure() -> type[Figure]:
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
