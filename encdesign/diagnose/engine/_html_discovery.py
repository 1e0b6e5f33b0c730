"""The HTML report's view of what lies beyond the catalog (issue 41): the residual spectrum
reaching the orders the finder located, each discovered model as a table, a figure of every
discovered term over the residual in its own frame, and the selection round of a refusal.
Reads only the document and the per-row arrays of :func:`._html.report_inputs`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ._html_base import ReportRows, _e, _figure, _located_orders, _num, _png, _table

MAX_SPECTRUM_ORDER = 1000
"""Highest shaft order the report's own spectrum reaches (the located orders set it)."""


def order_amplitudes(
    theta: np.ndarray, resid: np.ndarray, orders: np.ndarray, chunk: int = 64
) -> np.ndarray:
    """Amplitude (unit of ``resid``, mean over channels) of each shaft order in ``orders``:
    ``hypot(a, b)`` with ``a, b = 2/n sum r cos|sin(m theta)`` over the rows (theta (n,) rad,
    resid (n, C)); orders in chunks, so memory stays ``n * chunk``."""
    r = resid - resid.mean(axis=0)
    n = max(theta.size, 1)
    out = np.empty(orders.size)
    for i in range(0, orders.size, chunk):
        m = orders[i : i + chunk]
        ph = np.outer(theta, m)
        a = 2 * (np.cos(ph).T @ r) / n
        b = 2 * (np.sin(ph).T @ r) / n
        out[i : i + chunk] = np.mean(np.hypot(a, b), axis=1)
    return out


def spectrum_data(
    doc: Mapping[str, Any], rows: ReportRows | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(orders, base, final)`` amplitudes by integer shaft order for the spectrum figure.

    The document's ``spectrum`` stops at the base model's order limit; where an order was
    located beyond it and the rows carry the shaft angle, the spectrum is computed here from
    the kept rows' base and final residual up to 1.1 times the highest located order (at
    most :data:`MAX_SPECTRUM_ORDER`), so the figure shows the structure where it is."""
    sp = doc.get("spectrum") or {}
    top = max([0.0, *_located_orders(doc)])
    has = bool(sp.get("orders"))
    if has and top <= max(sp["orders"]):
        return (
            np.asarray(sp["orders"], float),
            np.asarray(sp["before"], float),
            np.asarray(sp["after"], float),
        )
    if rows is not None and rows["theta"] is not None and top >= 1 and rows["keep"].any():
        last = max(int(math.ceil(1.1 * top)), max(sp.get("orders") or [0]))
        o = np.arange(1, min(last, MAX_SPECTRUM_ORDER) + 1, dtype=float)
        keep = rows["keep"]
        th = rows["theta"][keep]
        return (
            o,
            order_amplitudes(th, rows["base_resid"][keep], o),
            order_amplitudes(th, rows["final_resid"][keep], o),
        )
    if not has:
        return None
    return (
        np.asarray(sp["orders"], float),
        np.asarray(sp["before"], float),
        np.asarray(sp["after"], float),
    )


def fig_spectrum(doc: Mapping[str, Any], rows: ReportRows | None = None) -> str | None:
    """Residual amplitude by integer order (base and final, :func:`spectrum_data`: up to the
    highest located order where the rows allow), located orders marked."""
    data = spectrum_data(doc, rows)
    if data is None:
        return None
    o, before, after = data
    Figure = _figure()
    fig = Figure(figsize=(10, 3.6))
    ax = fig.subplots()
    ms = 2.5 if o.size <= 100 else 1.0
    ax.semilogy(o, before + 1e-300, "o-", ms=ms, lw=0.7, label="base")
    ax.semilogy(o, after + 1e-300, "o-", ms=ms, lw=0.7, label="final")
    hi = float(np.nanmax(np.concatenate([before, after]))) if o.size else 0.0
    if hi > 0:  # orders the base model fits exactly (round-off) would squash the rest
        ax.set_ylim(bottom=max(float(np.nanmin(np.concatenate([before, after]))), 1e-4 * hi))
    first = True
    for m in _located_orders(doc):
        if o.min() <= m <= o.max():
            ax.axvline(m, color="tab:purple", lw=0.8, ls="--", label="located" if first else None)
            ax.annotate(
                f"{m:g}",
                (m, 1),
                xycoords=("data", "axes fraction"),
                fontsize=7,
                va="top",
                ha="left",
                color="tab:purple",
            )
            first = False
    beyond = [m for m in _located_orders(doc) if m > o.max()]
    if beyond:
        ax.set_title(
            "located beyond this spectrum (no shaft angle in the rows): "
            + ", ".join(f"{m:g}" for m in beyond[:8]),
            fontsize=8,
        )
    ax.set(xlabel="order (cycles per turn)", ylabel=f"amplitude ({doc['unit']}, channel mean)")
    ax.legend(loc="best", fontsize=8)
    return _png(fig)


def discovered_terms(doc: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """Every discovered term of the document (``unexplained[i].model.terms``), in order."""
    return [
        t for u in doc.get("unexplained") or [] for t in ((u.get("model") or {}).get("terms") or [])
    ]


FOLD_BINS = 48
"""Phase bins of the residual folded on a discovered term's line."""


def _directions(rows: ReportRows) -> np.ndarray:
    """+1 / -1 per row: the sign of the shaft angle's change within its run (0: unknown)."""
    th, run = rows["theta"], rows["run"]
    if th is None:
        return np.zeros(run.size)
    d = np.zeros(run.size)
    for r in np.unique(run):
        idx = np.flatnonzero(run == r)
        if idx.size > 1:
            d[idx] = np.sign(np.gradient(th[idx]))
    return d


def _term_phase(t: Mapping[str, Any], rows: ReportRows) -> np.ndarray | None:
    """The phase (rad) of a discovered term's line per row: ``m theta`` for an order (the
    shaft angle; ``None`` without it), ``2 pi f t`` for a frequency."""
    v = float(t.get("value", 0.0))
    if t.get("line_kind") == "hz":
        return 2 * math.pi * v * rows["t"]
    theta = rows["theta"]
    if theta is None or v == 0:
        return None
    return v * theta


def fig_discovered(doc: Mapping[str, Any], rows: ReportRows) -> str | None:
    """Each discovered term over the final catalog residual in its own frame: the residual
    of the term's channel (its head; else the largest) folded on the term's line phase
    (``m theta`` mod 2 pi for an order, ``2 pi f t`` for a frequency), averaged in
    :data:`FOLD_BINS` bins, per direction where the term follows it, with the term's
    sinusoid at the line's phase drawn over it and the model's amplitude and held-out gain in
    the title. The sinusoids of every discovered line are fitted together (least squares on
    the group's rows) and the other lines' are taken out of the residual before it is folded,
    so a panel shows its own line, not its neighbours leaking through an uneven coverage."""
    terms = [t for t in discovered_terms(doc) if _term_phase(t, rows) is not None]
    if not terms:
        return None
    terms = terms[:6]
    Figure = _figure()
    fig = Figure(figsize=(10, 2.8 * ((len(terms) + 1) // 2) + 0.4))
    axes = fig.subplots((len(terms) + 1) // 2, 2, squeeze=False).ravel()
    keep = rows["keep"]
    chans = rows["channels"]
    dirs = _directions(rows)
    lines: dict[tuple[str | None, float], np.ndarray] = {}
    for t in discovered_terms(doc):
        q = _term_phase(t, rows)
        if q is not None:
            lines.setdefault((t.get("line_kind"), float(t.get("value", 0.0))), q)
    for ax, t in zip(axes, terms):
        own = (t.get("line_kind"), float(t.get("value", 0.0)))
        others = [q for key, q in lines.items() if key != own]
        heads = t.get("heads") or []
        fr = str(t.get("frame", ""))
        if fr.startswith(("head ", "sensor ")) and len(heads) == 1 and heads[0] in chans:
            k = chans.index(heads[0])
        else:
            r = np.where(keep[:, None], rows["final_resid"], np.nan)
            k = int(np.argmax(np.nan_to_num(np.sqrt(np.nanmean(r**2, axis=0)))))
        ph = np.mod(_term_phase(t, rows), 2 * np.pi)
        mod = str(t.get("modulation", ""))
        split = mod in ("direction", "forward", "reverse", "per_cell") and (dirs != 0).any()
        groups = [(+1, "positive"), (-1, "negative")] if split else [(None, "all rows")]
        edges = np.linspace(0, 2 * np.pi, FOLD_BINS + 1)
        mids = 0.5 * (edges[1:] + edges[:-1])
        for (sgn, lab), col in zip(groups, ("tab:blue", "tab:red")):
            sel = keep & np.isfinite(rows["final_resid"][:, k])
            if sgn is not None:
                sel &= dirs == sgn
            if sel.sum() < 3:
                continue
            y, p = rows["final_resid"][sel, k], ph[sel]
            X = np.column_stack(
                [np.ones_like(p), np.cos(p), np.sin(p)]
                + [f(q[sel]) for q in others for f in (np.cos, np.sin)]
            )
            c = np.linalg.lstsq(X, y, rcond=None)[0]
            y = y - X[:, 3:] @ c[3:]
            b = np.clip(np.digitize(p, edges) - 1, 0, FOLD_BINS - 1)
            cnt = np.bincount(b, minlength=FOLD_BINS)
            mean = np.bincount(b, y, minlength=FOLD_BINS) / np.maximum(cnt, 1)
            mean[cnt == 0] = np.nan
            ax.plot(
                np.degrees(mids), mean, "o", ms=3, color=col, alpha=0.6, label=f"residual, {lab}"
            )
            g = np.linspace(0, 2 * np.pi, 200)
            ax.plot(
                np.degrees(g),
                c[1] * np.cos(g) + c[2] * np.sin(g) + c[0],
                "-",
                lw=1.4,
                color=col,
                label=f"term, {lab}",
            )
        pr = t.get("params") or {}
        unit = pr.get("unit", doc["unit"])
        ax.set_title(
            f"{t.get('line')} · {fr} · {mod}: amplitude {_num(pr.get('amplitude'), 3)} ± "
            f"{_num(pr.get('amplitude_se'), 2)} {unit},\nheld-out gain "
            f"{_num(t.get('heldout_gain_chi2'), 4)} χ²",
            fontsize=8,
        )
        what = "order" if t.get("line_kind") != "hz" else "frequency"
        ax.set(xlabel=f"phase of the {what} (deg)", ylabel=f"{chans[k]} ({doc['unit']})")
        ax.legend(loc="best", fontsize=6, markerscale=1.5)
    for ax in axes[len(terms) :]:
        ax.set_visible(False)
    fig.suptitle("discovered terms (outside the catalog) over the final residual", fontsize=9)
    return _png(fig)


def refusal_round(r: Mapping[str, Any]) -> str:
    """The selection round of a refusal as a table cell: ``round k`` (the forward round,
    ``rejected[i].round``), else ``after selection`` (the backward held-out check)."""
    k = r.get("round")
    return f"round {int(k)}" if k is not None else "after selection"


def model_parts(f: Mapping[str, Any], u: str) -> list[str]:
    """What discovery modelled of one unexplained finding (``model``), marked outside the
    catalog; ``not modelled`` with its reason where no term held."""
    m = f.get("model")
    if not isinstance(m, Mapping):
        return []
    if not m.get("terms"):
        return [f'<p class="small">discovery: not modelled: {_e(m.get("reason", "-"))}</p>']
    rows = []
    for t in m["terms"]:
        p = t.get("params") or {}
        sc = t.get("scaling") or {}
        law = "-"
        if sc:
            law = f"speed^({_num(sc.get('beta'), 3)} ± {_num(sc.get('beta_se'), 2)})"
        rows.append(
            [
                _e(t.get("line")),
                _e(t.get("frame")),
                _e(t.get("modulation")),
                _e(", ".join(map(str, t.get("heads") or [])) or "-"),
                _e(", ".join(map(str, t.get("runs") or [])) or "-"),
                _e(", ".join(t.get("directions") or []) or "-"),
                law,
                f"{_num(p.get('amplitude'))} ± {_num(p.get('amplitude_se'), 2)} {_e(u)}",
                _num(t.get("heldout_gain_chi2")),
                _num(t.get("inclusion_probability"), 2),
                _e(t.get("reading", "")),
            ]
        )
    out = [
        '<div class="discovered"><p><b>discovered model (outside the catalog)</b>: frame '
        f"{_e(m.get('frame') or '-')}; held-out gain {_num(m.get('heldout_gain_chi2'))} χ²; "
        f"{_e(m.get('selection', ''))}</p>",
        _table(
            [
                "line",
                "frame",
                "modulation",
                "heads",
                "runs",
                "directions",
                "scaling",
                "amplitude ± se",
                "held-out gain (χ²)",
                "inclusion",
                "reading",
            ],
            rows,
            "discovered",
        ),
    ]
    if m.get("reading"):
        out.append(f"<p>reading: {_e(m['reading'])}</p>")
    near = m.get("nearest_catalog") or []
    if near:
        out.append(
            '<p class="small">nearest catalog effects and why they were not enough: '
            + "; ".join(f"{_e(n.get('name'))}: {_e(n.get('reason', ''))}" for n in near)
            + "</p>"
        )
    out.append("</div>")
    return out
