"""A self-contained HTML report of a diagnosis (``encdesign diagnose REC.toml --html FILE``).

The report reads only the documented JSON document (:meth:`Diagnosis.to_json`,
``diagnosis.schema.json``) plus a few per-row arrays, both taken through ONE adapter,
:func:`report_inputs`, at the top of this module: the finder's internals may change, and the
adapter is the only place that knows them. Figures are PNG embedded as ``data:`` URIs; no
external CSS, JavaScript or font: the file opens offline.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..._html import result_html
from ._document import bounds_against, nuisance_rows
from ._html_base import (
    ReportRows,
    _e,
    _figure,
    _located,
    _located_cell,
    _located_intervals,
    _num,
    _param_cell,
    _png,
    _table,
    _where_text,
)
from ._html_discovery import (
    discovered_terms,
    fig_discovered,
    fig_spectrum,
    model_parts,
    refusal_round,
)

# ----------------------------------------------------------------------------------------
# The adapter: the only code that touches the finder's objects.


class Diagnosed(Protocol):
    """What the report reads of a diagnosis (a :class:`~encdesign.diagnose.Diagnosis`): its
    JSON document, and ``plot_data`` where it has one."""

    def to_json(self) -> dict[str, Any]: ...


def report_inputs(d: Diagnosed) -> tuple[dict[str, Any], ReportRows | None]:
    """The JSON document and the per-row arrays of a diagnosis (the report's only inputs).

    Args:
        d: a :class:`~encdesign.diagnose.Diagnosis` (anything with ``to_json()`` and
            ``plot_data``).

    Returns:
        ``(doc, rows)``: ``doc`` is ``d.to_json()``; ``rows`` is ``None`` when the diagnosis
        carries no plot data, else a dict of numpy arrays over the recording's rows in the
        finder's order: ``tau`` (n,) time with the runs end to end (s), ``t`` (n,) time within
        the run (s), ``run`` (n,) the run number as the document names it, ``keep`` (n,) bool
        (rows used by the fits), ``theta`` (n,) the shaft angle (rad) or ``None``,
        ``base_resid`` and ``final_resid`` (n, C) residuals of the base and final model (unit
        of the document), ``effects`` ``{name: (n, C)}`` each named effect's own fitted
        contribution (typed :class:`~encdesign.diagnose.engine._results.PlotData`; empty when the
        plot data has none), and ``channels`` (C names).
    """
    doc = d.to_json()
    pd = getattr(d, "plot_data", None)
    if pd is None:
        return doc, None
    prep = pd["prep"]
    run = np.asarray(prep.run)
    run_ids = np.asarray(getattr(prep, "run_ids", np.arange(run.max(initial=0) + 1)))
    theta = None
    for name in ("theta", "psi"):
        try:
            theta = np.asarray(prep.rows[name], dtype=float)
        except (KeyError, TypeError, ValueError):
            continue
        theta = theta[:, 0] if theta.ndim == 2 else theta
        break
    rows: ReportRows = {
        "tau": np.asarray(prep.rows["tau"], dtype=float),
        "t": np.asarray(prep.rows["t"], dtype=float),
        "run": run_ids[run] if run_ids.size > run.max(initial=0) else run,
        "keep": np.asarray(prep.keep, dtype=bool),
        "theta": theta,
        "base_resid": np.asarray(pd["base_resid"], dtype=float),
        "final_resid": np.asarray(pd["final_resid"], dtype=float),
        "effects": {
            str(k): np.asarray(v, dtype=float)
            for k, v in (getattr(pd, "effect_contributions", None) or {}).items()
        },
        "channels": [str(c) for c in prep.kd.channel_names],
    }
    return doc, rows


# ----------------------------------------------------------------------------------------

MAX_POINTS = 20_000
"""Rows drawn per scatter (evenly strided beyond it: a PNG shows no more)."""
MAX_PANELS = 8
"""Channels drawn in the per-channel figures (the largest base residuals first)."""

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em auto;
max-width:1100px;color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.2em;border-bottom:1px solid #ccc;
margin-top:1.6em}h3{font-size:1.05em}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}
td,th{border:1px solid #ccc;padding:.25em .5em;vertical-align:top;text-align:left}
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.verdict{display:inline-block;padding:.2em .7em;border-radius:.3em;color:#fff;font-weight:600}
.v-consistent{background:#2a7d2a}.v-missing_physics{background:#b5651d}
.v-unexplained{background:#a11}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.85em;color:#555}.small{font-size:.85em;color:#555}
details summary{cursor:pointer;color:#225}
"""


def _located_times(doc: Mapping[str, Any]) -> list[tuple[object, float, str]]:
    """``(run or None, t within the run (s), label)`` of every located time."""
    out: list[tuple[object, float, str]] = []
    for w in _located(doc):
        runs = w.get("runs") or [None]
        for t in w.get("times_s") or []:
            if t is not None:
                out += [(r, float(t), "located") for r in runs]
    for key, lab in (("glitches", "glitch"), ("count_jumps", "count jump"), ("gaps", "gap")):
        for g in doc.get(key) or []:
            if g.get("t_s") is not None:
                out.append((g.get("run"), float(g["t_s"]), lab))
    return out


def _tau_of(rows: ReportRows, run: object, t: float) -> float | None:
    """The end-to-end time of the row nearest ``t`` in ``run`` (any run when ``None``)."""
    sel = np.ones(rows["t"].size, bool) if run is None else rows["run"] == run
    if not sel.any():
        return None
    i = np.flatnonzero(sel)[int(np.argmin(np.abs(rows["t"][sel] - t)))]
    return float(rows["tau"][i])


def _spans(mask: np.ndarray, x: np.ndarray) -> list[tuple[float, float]]:
    """``(x_start, x_end)`` of the runs of True in ``mask``."""
    if not mask.any():
        return []
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    lo, hi = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    return [(float(x[a]), float(x[b])) for a, b in zip(lo, hi)]


def _stride(n: int) -> slice:
    return slice(None, None, max(1, math.ceil(n / MAX_POINTS)))


def _channels_by_size(rows: ReportRows) -> list[int]:
    r0 = np.where(rows["keep"][:, None], rows["base_resid"], np.nan)
    rms = np.sqrt(np.nanmean(r0**2, axis=0))
    order = list(np.argsort(-np.nan_to_num(rms)))
    return sorted(int(k) for k in order[:MAX_PANELS])


def fig_time(doc: Mapping[str, Any], rows: ReportRows) -> str:
    """Residual against time (runs end to end): base and final, excluded rows shaded,
    located times (findings, glitches, count jumps, gaps) as vertical lines."""
    Figure = _figure()
    ks = _channels_by_size(rows)
    fig = Figure(figsize=(10, 1.5 * len(ks) + 1.2))
    axes = fig.subplots(len(ks), 1, sharex=True, squeeze=False)[:, 0]
    tau, keep = rows["tau"], rows["keep"]
    s = _stride(tau.size)
    spans = _spans(~keep, tau)
    marks = [(_tau_of(rows, r, t), lab) for r, t, lab in _located_times(doc)]
    colors = {"located": "tab:purple", "glitch": "tab:orange", "count jump": "k", "gap": "0.4"}
    # issue 44 C: each located time's interval shaded; each run's start on the recording's
    # own t written at the top, so a time on the axis can be read on the recording's clock
    bands = [
        (_tau_of(rows, r0, t0), _tau_of(rows, r1, t1)) for r0, t0, r1, t1 in _located_intervals(doc)
    ]
    from ._plots import annotate_run_starts

    starts = annotate_run_starts(axes[0], tau, rows["t"], rows["run"])
    for ax, k in zip(axes, ks):
        for i, (a, b) in enumerate(x for x in bands if None not in x):
            ax.axvspan(
                a, b, color="tab:purple", alpha=0.25, label="located: interval" if i == 0 else None
            )
        for i in starts[1:]:
            ax.axvline(float(tau[i]), color="0.3", lw=0.5)
        ax.plot(tau[s], rows["base_resid"][s, k], ".", ms=1.5, color="tab:red", label="base")
        kk = keep[s]
        ax.plot(
            tau[s][kk], rows["final_resid"][s, k][kk], ".", ms=1.5, color="tab:blue", label="final"
        )
        for i, (a, b) in enumerate(spans):
            ax.axvspan(a, b, color="0.8", alpha=0.6, label="excluded" if i == 0 else None)
        seen = set()
        for x, lab in marks:
            if x is not None:
                ax.axvline(
                    x, color=colors[lab], lw=0.8, ls="--", label=None if lab in seen else lab
                )
                seen.add(lab)
        ax.set_ylabel(f"{rows['channels'][k]} ({doc['unit']})", fontsize=8)
    axes[0].legend(fontsize=7, loc="upper right", ncol=5, markerscale=5)
    axes[-1].set_xlabel(
        "time, runs end to end, pauses removed (s); each run's start on the recording's t above"
    )
    return _png(fig)


def fig_heads(doc: Mapping[str, Any], rows: ReportRows) -> str:
    """Per channel (head): residual RMS of the base and final model over the kept rows
    against the noise, and the base residual folded on the shaft angle."""
    Figure = _figure()
    keep = rows["keep"]
    C = rows["base_resid"].shape[1]
    r0 = np.sqrt(np.mean(rows["base_resid"][keep] ** 2, axis=0)) if keep.any() else np.zeros(C)
    r1 = np.sqrt(np.mean(rows["final_resid"][keep] ** 2, axis=0)) if keep.any() else np.zeros(C)
    theta = rows["theta"]
    has_theta = theta is not None
    fig = Figure(figsize=(10, 3.6))
    axes = fig.subplots(1, 2 if has_theta else 1, squeeze=False)[0]
    x = np.arange(C)
    axes[0].bar(x - 0.2, r0, 0.4, color="tab:red", label="base")
    axes[0].bar(x + 0.2, r1, 0.4, color="tab:blue", label="final")
    noise = (doc.get("noise") or {}).get("per_channel") or []
    if len(noise) == C:
        axes[0].plot(x, noise, "k_", ms=18, mew=2, label="noise")
    axes[0].set_xticks(x, rows["channels"], fontsize=7, rotation=45 if C > 6 else 0)
    axes[0].set(ylabel=f"RMS ({doc['unit']})", title="per channel")
    axes[0].legend(loc="best", fontsize=7)
    if has_theta:
        ph = np.degrees(np.mod(theta[keep], 2 * np.pi))
        s = _stride(ph.size * min(C, MAX_PANELS))
        for k in _channels_by_size(rows):
            axes[1].plot(
                ph[s], rows["base_resid"][keep][s, k], ".", ms=1, label=rows["channels"][k]
            )
        axes[1].set(
            xlabel="angle mod one turn (deg)",
            ylabel=f"base residual ({doc['unit']})",
            title="base residual by angle, per channel",
        )
        axes[1].legend(loc="best", fontsize=6, markerscale=6, ncol=2)
    return _png(fig)


def fitted_curves(doc: Mapping[str, Any], rows: ReportRows) -> list[tuple[str, np.ndarray]]:
    """``[(name, (n, C) contribution), ...]``: each named effect's own fitted contribution
    (the typed results' per-effect arrays, in the order of ``effects``); effects named from
    a lattice (not fitted) have none. Without per-effect arrays, one curve: the named
    effects together (base residual minus final residual)."""
    own = rows["effects"]
    curves = [(e["name"], own[e["name"]]) for e in doc.get("effects") or [] if e["name"] in own]
    if curves:
        return curves
    return [("named effects", rows["base_resid"] - rows["final_resid"])]


def fig_fitted(doc: Mapping[str, Any], rows: ReportRows) -> str | None:
    """Each named effect's own fitted contribution (one curve per effect,
    :func:`fitted_curves`) drawn over the base residual it explains, on the channel where
    they are largest: against time and, where the shaft angle is known, folded on the
    angle."""
    if not doc.get("effects"):
        return None
    Figure = _figure()
    keep = rows["keep"]
    curves = fitted_curves(doc, rows)
    model = sum(np.abs(c) for _, c in curves)
    k = int(np.argmax(np.sqrt(np.mean(model[keep] ** 2, axis=0)))) if keep.any() else 0
    theta = rows["theta"]
    has_theta = theta is not None
    fig = Figure(figsize=(10, 3.6))
    axes = fig.subplots(1, 2 if has_theta else 1, squeeze=False)[0]
    tau = rows["tau"][keep]
    s = _stride(tau.size)
    b = rows["base_resid"][keep, k]
    colors = ("tab:green", "tab:orange", "tab:purple", "tab:red", "tab:blue")
    axes[0].plot(tau[s], b[s], ".", ms=1.5, color="0.55", label="base residual")
    for i, (name, c) in enumerate(curves):
        m = c[keep, k]
        axes[0].plot(tau[s], m[s], "-", lw=0.8, color=colors[i % len(colors)], label=name)
    axes[0].set(xlabel="time, runs end to end (s)", ylabel=f"{rows['channels'][k]} ({doc['unit']})")
    axes[0].legend(loc="best", fontsize=7, markerscale=5)
    if has_theta:
        ph = np.degrees(np.mod(theta[keep], 2 * np.pi))
        o = np.argsort(ph)[s]
        axes[1].plot(ph[o], b[o], ".", ms=1.5, color="0.55", label="base residual")
        for i, (name, c) in enumerate(curves):
            m = c[keep, k]
            axes[1].plot(ph[o], m[o], ".", ms=1.5, color=colors[i % len(colors)], label=name)
        axes[1].set(xlabel="angle mod one turn (deg)", ylabel=f"{rows['channels'][k]}")
        axes[1].legend(loc="best", fontsize=7, markerscale=5)
    names = ", ".join(name for name, _ in curves)
    fig.suptitle(f"fitted: {names} (channel {rows['channels'][k]})", fontsize=9)
    return _png(fig)


def fig_before_after(doc: Mapping[str, Any], rows: ReportRows | None) -> str:
    """RMS per model step (base, then each named effect), fitted and held out, against the
    noise; and the distribution of the base and final residual."""
    from ._plots import rms_bars, rms_steps

    Figure = _figure()
    fig = Figure(figsize=(10, 3.4))
    axes = fig.subplots(1, 2 if rows is not None else 1, squeeze=False)[0]
    names, fitted, held = rms_steps(doc)
    held = [np.nan if h is None else h for h in held]
    rms_bars(axes[0], names, fitted, held, fontsize=8)
    noise = (doc.get("noise") or {}).get("per_channel") or []
    if noise:
        axes[0].axhline(float(np.mean(noise)), color="k", ls=":", label="noise")
    axes[0].set(ylabel=f"residual RMS ({doc['unit']})", title="before / after each step")
    axes[0].legend(loc="best", fontsize=7)
    if rows is not None:
        keep = rows["keep"]
        for key, lab, col in (
            ("base_resid", "base", "tab:red"),
            ("final_resid", "final", "tab:blue"),
        ):
            v = rows[key][keep].ravel()
            v = v[np.isfinite(v)]
            if v.size:
                axes[1].hist(v, bins=80, histtype="step", color=col, label=lab, density=True)
        axes[1].set(xlabel=f"residual ({doc['unit']})", ylabel="density", title="residuals")
        axes[1].legend(loc="best", fontsize=7)
    return _png(fig)


def _fig_block(fid: str, title: str, img: str | None, caption: str) -> str:
    if img is None:
        cap = f"{_e(title)}: not applicable ({_e(caption)})"
        return f'<figure id="{fid}"><figcaption>{cap}</figcaption></figure>'
    cap = f"<figcaption>{_e(caption)}</figcaption>"
    return f'<figure id="{fid}"><h3>{_e(title)}</h3>{img}{cap}</figure>'


def _summary_parts(doc: dict) -> list[str]:
    """The residual, noise and goodness-of-fit sections."""
    parts: list[str] = []
    u = doc["unit"]
    g = doc.get("goodness_of_fit") or {}
    ho = doc.get("heldout") or {}
    # summary: RMS, noise, goodness of fit
    parts.append('<h2 id="summary">Residual, noise and goodness of fit</h2>')
    parts.append(
        _table(
            ["", f"fitted RMS ({u})", f"held-out RMS ({u})"],
            [
                ["base model", _num(doc["rms_before"]), _num(doc["heldout_rms_before"])],
                ["final model", _num(doc.get("rms_final")), _num(doc.get("heldout_rms_final"))],
            ],
        )
    )
    nz = doc.get("noise") or {}
    chans = nz.get("channels") or [str(i) for i in range(len(nz.get("per_channel") or []))]
    parts.append('<h3 id="noise">Noise per channel</h3>')
    parts.append(
        _table(
            ["channel", f"noise σ ({u})"],
            [
                [_e(c), f'<span class="num">{_num(s)}</span>']
                for c, s in zip(chans, nz.get("per_channel") or [])
            ],
        )
    )
    if nz.get("method"):
        parts.append(f'<p class="small">{_e(nz["method"])}</p>')
    parts.append('<h3 id="gof">Goodness of fit</h3>')
    if g:
        parts.append(
            _table(
                ["test", "z", "p", "α", "passes"],
                [
                    [
                        _e(g.get("test", "")),
                        _num(g.get("statistic_z")),
                        _num(g.get("p_value")),
                        _num(g.get("alpha")),
                        _num(bool(g.get("passes"))),
                    ]
                ],
            )
        )
    else:
        parts.append("<p>not computed</p>")
    if ho:
        parts.append(
            f'<p class="small">held out: {_e(ho.get("k"))} folds; {_e(ho.get("scheme", ""))}</p>'
        )
    return parts


def _bound_parts(doc: dict) -> list[str]:
    """The detection bounds (issue 44 F): the smallest size of each catalog effect not named,
    per head or sensor, this record would have revealed against the final model."""
    bounds = doc.get("detection_bounds")
    if not bounds:
        return []
    rows = [
        [
            _e(b["effect"]),
            _e(b["parameter"]),
            _e(b["where"]),
            "-" if b["bound"] is None else f'<span class="num">{_num(b["bound"])}</span>',
            _e(b["unit"]),
            _e(b.get("note") or b["set_by"] or ""),
            _e(b["at"]),
        ]
        for b in bounds
    ]
    parts = ['<h2 id="bounds">What this record could have shown</h2>']
    parts.append(
        _table(["effect", "size", "on", "smallest revealed", "unit", "set by", "at"], rows)
    )
    note = (
        f"Computed {bounds_against(doc)}. About 50 % power at the finder's own thresholds: "
        "1.5x the bound is found almost always, half of it almost never."
    )
    if doc.get("detection_bounds_not_covered"):
        note += " Not bounded (no probe yet): " + ", ".join(doc["detection_bounds_not_covered"])
    parts.append(f'<p class="small">{_e(note)}</p>')
    return parts


def _effect_parts(doc: dict) -> list[str]:
    """The named effects, and the alternatives and refusals."""

    parts: list[str] = []
    u = doc["unit"]
    # effects
    parts.append('<h2 id="effects">Named effects</h2>')
    effects = doc.get("effects") or []
    if not effects:
        parts.append("<p>none</p>")
    prev = doc.get("heldout_rms_before")
    for i, e in enumerate(effects, 1):
        h = e.get("heldout_rms_after")
        gain = (prev - h) if (prev is not None and h is not None) else None
        rel = f" ({100 * gain / prev:.1f} %)" if gain is not None and prev else ""
        parts.append(f'<h3 class="effect" id="effect-{i}">{i}. {_e(e["name"])}</h3>')
        parts.append(f"<p>{_e(e.get('explanation', ''))}</p>")
        parts.append(
            _table(
                [
                    "fitted RMS after",
                    "held-out RMS after",
                    "held-out gain",
                    "ΔBIC",
                    "collinearity",
                    "share",
                    "channels",
                ],
                [
                    [
                        f"{_num(e.get('rms_after'))} {_e(u)}",
                        f"{_num(h)} {_e(u)}",
                        f"{_num(gain)} {_e(u)}{_e(rel)}",
                        _num(e.get("delta_bic")),
                        _num(e.get("collinearity")),
                        _num(e.get("share")),
                        _e(", ".join(map(str, e.get("channels") or [])) or "-"),
                    ]
                ],
            )
        )
        prows = [[_e(k), _param_cell(p)] for k, p in (e.get("params") or {}).items()]
        prows += [
            [_e(k) + " (derived)", _param_cell(p) if isinstance(p, Mapping) else _e(p)]
            for k, p in (e.get("derived") or {}).items()
        ]
        parts.append(_table(["parameter", "value ± standard error"], prows, "params"))
        for n in e.get("notes") or []:
            parts.append(f'<p class="small">note: {_e(n)}</p>')
        prev = h if h is not None else prev
    # alternatives and refusals
    parts.append('<h2 id="alternatives">Alternatives and refusals</h2>')
    alt = [
        [_e(e["name"]), "confounded with " + _e(c.get("name")), _e(c.get("reason", "")), "-", "-"]
        for e in effects
        for c in (e.get("confounded_with") or [])
    ]
    alt += [
        [
            _e(e["name"]),
            f"named although doubted ({_e(e['doubt']['rule'])}); alternative " + _e(a.get("name")),
            _e(a.get("reason", "")) + "; tell apart: " + _e(a.get("separate_by", "")),
            _num(a.get("delta_bic")),
            "-",
        ]
        for e in effects
        if e.get("doubt")
        for a in (e.get("alternatives") or [])
    ]
    alt += [
        [
            _e(r.get("name")),
            "rejected",
            _e(r.get("reason", "")),
            _num(r.get("delta_bic")),
            refusal_round(r),
        ]
        for r in doc.get("rejected") or []
    ]
    alt += [
        [_e(r.get("name")), "not testable", _e(r.get("reason", "")), "-", "-"]
        for r in doc.get("not_testable") or []
    ]
    parts.append(
        _table(["candidate", "outcome", "reason", "ΔBIC", "round"], alt, "alternatives")
        if alt
        else "<p>none</p>"
    )
    return parts


def _located_parts(doc: dict) -> list[str]:
    """Unexplained and located structure, and the nuisances."""

    parts: list[str] = []
    u = doc["unit"]
    # located structure
    parts.append('<h2 id="unexplained">Unexplained structure</h2>')
    un = doc.get("unexplained") or []
    parts.append(
        _table(
            ["view", "where", f"RMS ({u})", "discovered"],
            [
                [
                    _e(f.get("view", "-")),
                    _where_text(f.get("where"))
                    + ("<br>" + _located_cell(f["located_time"]) if f.get("located_time") else ""),
                    _num(f.get("rms")),
                    _e(
                        "-"
                        if not isinstance(f.get("model"), Mapping)
                        else f"{len(f['model'].get('terms') or [])} term(s)"
                        if f["model"].get("terms")
                        else "not modelled"
                    ),
                ]
                for f in un
            ],
        )
        if un
        else "<p>none</p>"
    )
    for i, f in enumerate(un, 1):
        mp = model_parts(f, u)
        if mp:
            parts.append(
                f'<h3 id="discovered-{i}">Unexplained {i}: {_where_text(f.get("where"))}</h3>'
            )
            parts += mp
    fb = doc.get("findings_before") or []
    if fb:
        parts.append('<h3 id="findings">Located in the base residual</h3>')
        parts.append(
            _table(
                ["view", "where", f"RMS ({u})"],
                [
                    [_e(f.get("view", "-")), _where_text(f.get("where")), _num(f.get("rms"))]
                    for f in fb
                ],
            )
        )
    parts.append('<h2 id="nuisances">Excluded segments, glitches, count jumps, gaps</h2>')
    nui = [[_e(c) for c in row] for row in nuisance_rows(doc)]
    parts.append(_table(["what", "run", "t (s)", "detail"], nui) if nui else "<p>none</p>")
    return parts


def _figure_parts(doc: dict, rows: ReportRows | None) -> list[str]:
    """The embedded figures."""

    parts: list[str] = []
    effects = doc.get("effects") or []
    # figures
    parts.append('<h2 id="figures">Figures</h2>')
    if rows is None:
        parts.append("<p>no per-row data in this diagnosis: figures from the document only</p>")
    else:
        parts.append(
            _fig_block(
                "fig-time",
                "Residual against time",
                fig_time(doc, rows),
                "base (red) and final (blue) residual; grey: rows excluded from every fit; "
                "dashed: located times",
            )
        )
    parts.append(
        _fig_block(
            "fig-spectrum",
            "Residual spectrum by order",
            fig_spectrum(doc, rows),
            "amplitude of integer shaft orders in the base and final residual, up to the "
            "highest order the finder located; dashed: orders the finder located",
        )
    )
    if rows is not None and discovered_terms(doc):
        parts.append(
            _fig_block(
                "fig-discovered",
                "Discovered terms in their own frame",
                fig_discovered(doc, rows),
                "the final (catalog) residual folded on each discovered term's line phase, "
                "binned, per direction where the term follows it, with the term's sinusoid "
                "over it (outside the catalog)",
            )
        )
    if rows is not None:
        parts.append(
            _fig_block(
                "fig-heads",
                "Per head",
                fig_heads(doc, rows),
                "RMS per channel (base, final, noise) and the base residual folded on the angle",
            )
        )
        parts.append(
            _fig_block(
                "fig-fitted",
                "Fitted effects over the base residual",
                fig_fitted(doc, rows),
                "no named effect"
                if not effects
                else "each named effect's own fitted contribution, one curve each: "
                + ", ".join(n for n, _ in fitted_curves(doc, rows)),
            )
        )
    parts.append(
        _fig_block(
            "fig-before-after",
            "Before / after",
            fig_before_after(doc, rows),
            "residual RMS per model step, fitted and held out, and residual distributions",
        )
    )
    for n in doc.get("notes") or []:
        parts.append(f'<p class="small">note: {_e(n)}</p>')
    if doc.get("report"):
        parts.append(
            '<h2 id="text">Text report</h2><details><summary>show</summary>'
            f"<pre>{_e(doc['report'])}</pre></details>"
        )
    return parts


def render_html(d: Diagnosed) -> str:
    """The whole report of a diagnosis as one HTML string (see the module docstring)."""
    doc, rows = report_inputs(d)
    verdict = doc["verdict"]
    parts = [
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">',
        f"<title>encdesign diagnosis: {_e(doc.get('recording') or doc['kind'])}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>Diagnosis of {_e(doc.get('recording') or 'a recording')}</h1>",
        f'<p id="verdict">kind <b>{_e(doc["kind"])}</b> · verdict '
        f'<span class="verdict v-{_e(verdict)}">{_e(verdict)}</span> · status '
        f"{_e(doc.get('status', '-'))} · {_e(doc.get('format', ''))}</p>",
    ]
    parts += _summary_parts(doc)
    parts += _effect_parts(doc)
    parts += _located_parts(doc)
    parts += _bound_parts(doc)  # after what the record showed: what else it could have
    parts += _figure_parts(doc, rows)
    parts.append("</body></html>\n")
    return "\n".join(parts)


def notebook_html(d: Diagnosed) -> str:
    """A diagnosis in a notebook (``Diagnosis._repr_html_``): the report's verdict line and
    its tables (residual, noise, goodness of fit, named effects, alternatives and refusals,
    located structure, nuisances), without the figures (each a rendered PNG; the full report
    is :func:`render_html`)."""
    doc = d.to_json()
    verdict = doc["verdict"]
    headline = (
        f"kind <b>{_e(doc['kind'])}</b> · verdict "
        f'<span class="verdict v-{_e(verdict)}">{_e(verdict)}</span> · status '
        f"{_e(doc.get('status', '-'))}"
    )
    title = f"Diagnosis of {doc.get('recording') or 'a recording'}"
    return result_html(
        title,
        headline,
        sections=_summary_parts(doc) + _effect_parts(doc) + _located_parts(doc) + _bound_parts(doc),
    )


def write_html(d: Diagnosed, path: str | Path) -> Path:
    """Write :func:`render_html` of ``d`` to ``path`` atomically."""
    from ...io._paths import atomic_write_text

    p = Path(path)
    atomic_write_text(p, render_html(d))
    return p
