"""Stage 6 of the engine, the **document**: parameters as JSON, the value-lattice
quantization, the order spectrum and the plain-text report."""

from __future__ import annotations

import math

import numpy as np

from ._fit import FitResult, Term
from ._lattice import detect_lsb
from ._located import describe as describe_located
from ._protocol import Prepared
from ._settings import FinderSettings
from ._views import order_sums, run_spans

# ----------------------------------------------------------------------------- run + JSON


def jsonable(v):
    a = np.asarray(v, float)
    a = np.where(np.isfinite(a), a, np.nan)
    if a.ndim == 0:
        return None if np.isnan(a) else float(a)
    return [jsonable(x) for x in a]


def term_params(term: Term, fit: FitResult, index: int) -> dict:
    """``{name: {"value", "se", "unit"}}`` of one fitted term (se null where held)."""
    s0, _ = fit.slices[index]
    se_all = np.sqrt(np.maximum(np.diag(fit.cov), 0.0)) if fit.cov.size else np.zeros(0)
    out = {}
    pos = s0
    for q in term.cand.params:
        m = term.free[q.name]
        se = np.full(m.shape, np.nan)
        k = int(m.sum())
        se[m] = se_all[pos : pos + k] if k else []
        pos += k
        out[q.name] = {"value": jsonable(term.values[q.name]), "se": jsonable(se), "unit": q.unit}
    return out


def recording_time(prep, tau: float) -> tuple[float, int]:
    """A time on the end-to-end axis ``tau`` (runs laid end to end, pauses removed) as
    ``(t, run)``: the recording's own ``t`` (s) and the run id, from the last row at or
    before it (the first row when it is before every row)."""
    taus = np.asarray(prep.rows["tau"], float)
    i = int(np.clip(np.searchsorted(taus, tau, side="right") - 1, 0, taus.size - 1))
    t_i = float(prep.rows.take("t", np.array([i]))[0])
    return t_i + (float(tau) - float(taus[i])), int(prep.run_ids[prep.run[i]])


def global_times_in_own_clock(prep, term: Term, params: dict) -> dict:
    """``params`` (:func:`term_params`) with each ``global_time`` parameter moved from the
    end-to-end axis to the recording's own ``t``, with its ``run`` (the se is the same: a
    shift within a run)."""
    for q in term.cand.params:
        if not q.global_time or q.name not in params:
            continue
        v = np.ravel(np.asarray(params[q.name]["value"], float))
        conv = [recording_time(prep, float(x)) for x in v]
        vals = [c[0] for c in conv]
        runs = [c[1] for c in conv]
        params[q.name]["value"] = vals[0] if np.ndim(params[q.name]["value"]) == 0 else vals
        params[q.name]["run"] = runs[0] if len(runs) == 1 else runs
        params[q.name]["clock"] = "the recording's t"
    return params


def se_dict(term: Term, fit: FitResult, index: int) -> dict[str, np.ndarray]:
    s0, _ = fit.slices[index]
    se_all = np.sqrt(np.maximum(np.diag(fit.cov), 0.0)) if fit.cov.size else np.zeros(0)
    out, pos = {}, s0
    for q in term.cand.params:
        m = term.free[q.name]
        se = np.full(m.shape, np.nan)
        k = int(m.sum())
        se[m] = se_all[pos : pos + k] if k else []
        pos += k
        out[q.name] = se
    return out


def scan_order_of(limit: int, order: int, settings: FinderSettings) -> int:
    """Highest order the views scan for a base of ``order``: twice it, at least
    ``settings.scan_order_min``, within what the record resolves."""
    return int(min(limit, max(2 * order, settings.scan_order_min)))


SWEEP_WINDOW = 9
"""Rows of the centred moving mean of :func:`_sweep_grid` (odd)."""


def _sweep_grid(v: np.ndarray, keep: np.ndarray, run: np.ndarray, lat, coherence: float) -> bool:
    """Whether a value lattice is only the time grid of a steady sweep.

    An evenly sampled steady sweep advances a fixed number of "steps" per sample: its values
    sit on a lattice without any quantizer (then the reading is not coarse, the sampling is).
    The tell is the unquantized signal: the centred moving mean over ``SWEEP_WINDOW`` rows of a
    quantized reading follows the signal between the levels (its phase ``u`` on the lattice
    spreads over the step, dithered or not), while that of a sampled sweep stays on the lattice
    (``|mean exp(2 pi i u)| > prep.settings.sweep_coherence``)."""
    q = float(lat.lsb_rad)
    z, n = 0j, 0
    for r, (a, b) in run_spans(run):
        idx = np.flatnonzero(keep[a:b]) + a
        if idx.size < SWEEP_WINDOW:
            continue
        cut = np.flatnonzero(np.diff(idx) > 1) + 1  # contiguous kept stretches
        for part in np.split(idx, cut):
            if part.size < SWEEP_WINDOW:
                continue
            ma = np.convolve(v[part], np.ones(SWEEP_WINDOW) / SWEEP_WINDOW, mode="valid")
            u = (ma - lat.offset_rad.get(int(r), 0.0)) / q
            z += np.sum(np.exp(2j * np.pi * u))
            n += ma.size
    return n > 0 and abs(z) / n > coherence


LATTICE_ROWS = 1 << 14
"""Rows of each run (from its start) that the value-lattice test of :func:`lattice_effect`
reads."""


def lattice_effect(prep: Prepared, rms_final: float, heldout_final: float | None) -> dict | None:
    """``quantization`` named from the value lattice of the readings, not fitted.

    Per channel, the readings of the kept rows (each run with its own zero) are tested for a
    lattice ``c_r + q k`` (:func:`._lattice.detect_lsb`); a channel whose floor
    ``q^2 / 12`` is at least ``settings.lattice_noise_share`` of its measured noise variance (which,
    estimated from the data, includes the quantization) carries the effect. A dithered
    staircase (noise ahead of the quantizer above about ``q / 2``) leaves nothing for a
    model of the reading to fit: the finding is the LSB itself, so ``delta_bic``,
    ``collinearity`` and the held-out change are ``None`` (no parameter was fitted), and the
    residual RMS are the final model's. ``None`` when no channel qualifies."""

    # the first LATTICE_ROWS rows of each run: a lattice holds in any stretch of the
    # readings, and the test's sorts and gaps then stay bounded (10^7 rows: +1.5 GB)
    pieces = [(a, min(b, a + LATTICE_ROWS)) for _, (a, b) in run_spans(prep.run)]
    reading = np.concatenate(
        [np.asarray(prep.rows.column("reading", a, b), float).reshape(b - a, -1) for a, b in pieces]
    )
    keep = np.concatenate([prep.keep[a:b] for a, b in pieces])
    run = np.concatenate([prep.run[a:b] for a, b in pieces])
    chans, lsb, share, offsets = [], [], [], []
    for k in range(reading.shape[1]):
        lat = detect_lsb(reading[keep, k], run[keep], settings=prep.settings)
        if lat.lsb_rad is None or _sweep_grid(
            reading[:, k], keep, run, lat, prep.settings.sweep_coherence
        ):
            continue
        sh = (lat.lsb_rad**2 / 12.0) / float(prep.sigma[k]) ** 2
        if sh >= prep.settings.lattice_noise_share:
            chans.append(k)
            lsb.append(float(lat.lsb_rad))
            share.append(float(min(sh, 1.0)))
            offsets.append([float(lat.offset_rad[r]) for r in sorted(lat.offset_rad)])
    if not chans:
        return None
    one = len(chans) == 1

    def val(v):
        return v[0] if one else v

    u = prep.kd.unit
    q = np.asarray(lsb)
    names = [prep.kd.channel_names[k] for k in chans]
    return {
        "name": "quantization",
        "params": {"lsb_rad": {"value": val(lsb), "se": None, "unit": u}},
        "derived": {
            "counts_per_turn": {"value": val((2 * np.pi / q).tolist()), "se": None, "unit": "1"},
            "bits_per_turn": {
                "value": val(np.log2(2 * np.pi / q).tolist()),
                "se": None,
                "unit": "bit",
            },
            "floor_rms_rad": {"value": val((q / math.sqrt(12.0)).tolist()), "se": None, "unit": u},
            "noise_share": {"value": val(share), "se": None, "unit": "1"},
            "lattice_offset_rad": {"value": val(offsets), "se": None, "unit": u},
        },
        "channels": names,
        "rms_after": rms_final,
        "heldout_rms_after": heldout_final,
        "delta_bic": None,
        "delta_heldout_chi2": None,
        "collinearity": None,
        "share": 0.0,
        "size_rms": float(np.mean(q) / math.sqrt(12.0)),
        "notes": [
            f"every reading of {', '.join(names)} lies on a lattice of "
            + ", ".join(f"{x:.4g}" for x in lsb)
            + f" {u} (one LSB); its floor LSB/sqrt(12) is "
            + ", ".join(f"{100 * x:.0f}%" for x in share)
            + " of the measured noise variance: named from the lattice, not fitted (the "
            "staircase, dithered by the noise ahead of the quantizer, leaves no structure to "
            "fit), so delta_bic, collinearity and the held-out change do not apply"
        ],
        "explanation": "a reading of finite resolution: the readings lie on a value lattice of "
        "one LSB, a uniform error of +-LSB/2 (RMS LSB/sqrt(12)) that sets the noise floor",
        "confounded_with": [],
    }


def order_spectrum(prep: Prepared, r0: np.ndarray, r1: np.ndarray, max_order: int) -> dict:
    """Amplitude (unit of y, mean over channels) of integer shaft orders ``1..max_order`` in
    the base and the final residual (least squares over the kept rows), at most
    ``settings.spectrum_order_max`` of them."""

    M = int(min(max_order, prep.settings.spectrum_order_max))
    out = {"orders": list(range(1, M + 1)), "before": [], "after": []}
    N, _, _, _, sums = order_sums(prep, "theta", [r0, r1], np.arange(1, M + 1))
    for (Bc, Bs), key in zip(sums, ("before", "after")):
        a = 2 * Bc / max(N, 1)
        b = 2 * Bs / max(N, 1)
        out[key] = [float(v) for v in np.mean(np.hypot(a, b), axis=1)]
    return out


def significant_channels(
    term: Term, fit: FitResult, idx: int, C: int, R: int, settings: FinderSettings
):
    """Channels whose per-channel parameters differ from zero by more than
    ``settings.significant_channel_se`` standard errors (``None`` when the term has no
    per-channel parameter)."""
    se = se_dict(term, fit, idx)
    per = [q for q in term.cand.params if q.shape in ("channels", "runs*channels")]
    if not per or C == 1:
        return None
    z = np.zeros(C)
    for q in per:
        v = np.abs(term.values[q.name]) / np.where(se[q.name] > 0, se[q.name], np.inf)
        v = np.nan_to_num(v)
        z = np.maximum(z, v.reshape(-1, C).max(0))
    return [k for k in range(C) if z[k] > settings.significant_channel_se]


def _g(x, digits: int = 4) -> str:
    """A number as text (``-`` for none / non-finite)."""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return "-" if x is None else str(x)
    return f"{v:.{digits}g}" if math.isfinite(v) else "-"


def nuisance_rows(doc: dict) -> list[tuple[str, str, str, str]]:
    """``(what, run, time, detail)`` text of each excluded segment, glitch, count jump and
    gap of a diagnosis document: the one formatter of the plain-text report's lines and
    the HTML report's nuisance table (time in s within the run; detail in the document's
    unit)."""
    u = doc.get("unit", "")
    rows = [
        (
            "excluded",
            str(s.get("run")),
            f"{_g(s.get('t_start_s'))}..{_g(s.get('t_end_s'))}",
            f"{s.get('n_rows')} rows: {s.get('reason', '')}",
        )
        for s in doc.get("excluded_segments") or []
    ]
    rows += [
        ("glitch", str(s.get("run")), _g(s.get("t_s"), 6), f"channel {s.get('channel', '-')}")
        for s in doc.get("glitches") or []
    ]
    rows += [
        (
            "count jump",
            str(s.get("run")),
            _g(s.get("t_s"), 6),
            f"channel {s.get('channel', '-')}, size {_g(s.get('size'))} {u}",
        )
        for s in doc.get("count_jumps") or []
    ]
    rows += [
        ("gap", str(s.get("run")), _g(s.get("t_s"), 6), f"for {_g(s.get('duration_s'), 3)} s")
        for s in doc.get("gaps") or []
    ]
    return rows


def _model_lines(m: dict | None, u: str) -> list[str]:
    """The report lines of a finding's discovered model (issue 41)."""
    if not m:
        return []
    if not m["terms"]:
        return [f"  not modelled: {m.get('reason', '')}"]
    out = []
    for t in m["terms"]:
        p = t["params"]
        sc = t.get("scaling")
        law = ""
        if sc:
            se = sc["beta_se"]
            law = f", speed^({sc['beta']:.2f}" + (f" +- {se:.2g})" if se is not None else ")")
        out.append(
            f"  discovered (outside the catalog): {t['line']}, {t['frame']}, {t['modulation']}"
            f"{law}; amplitude {p['amplitude']:.3g} +- {p['amplitude_se']:.2g} {u}; held-out "
            f"gain {t['heldout_gain_chi2']:.4g} (chi2) at entry"
            + (
                f", {t['heldout_gain_drop_one_chi2']:.4g} if only it were removed"
                if "heldout_gain_drop_one_chi2" in t
                else ""
            )
            + "; inclusion "
            f"{t['inclusion_probability']:.0%}"
        )
        where = [
            f"{lab} {', '.join(map(str, t.get(key) or []))}"
            for key, lab in (("heads", "heads"), ("runs", "runs"), ("directions", "directions"))
            if t.get(key)
        ]
        if where:
            out.append("    on " + "; ".join(where))
    out.append(f"  reading: {m['reading']}")
    near = m.get("nearest_catalog") or []
    if near:
        out.append(
            "  nearest catalog effects (not enough): "
            + "; ".join(f"{n['name']}: {n.get('reason', '')}" for n in near)
        )
    return out


def bounds_against(doc: dict) -> str:
    """In words, the model the detection bounds are computed against (issue 44 F)."""
    ref = doc.get("detection_bounds_reference") or {}
    if not ref.get("named"):
        return "against the base model"
    out = "against the base model and the named effects (" + ", ".join(ref["named"]) + ")"
    if ref.get("located_excess_chi2"):
        chi2 = ref["located_excess_chi2"]
        out += f", beside the structure left unexplained (excess chi2 {chi2:.3g})"
    return out


def bound_lines(doc: dict) -> list[str]:
    """The report's lines on the detection bounds (issue 44 F): of each catalog effect not
    named, against the final model."""
    bounds = doc.get("detection_bounds")
    if not bounds:
        return []
    lines = [
        f"smallest size this record would have revealed, {bounds_against(doc)} (about 50 % "
        "power at the finder's thresholds; 1.5x it is found almost always, half of it almost "
        "never):"
    ]
    for b in bounds:
        size = "not revealed at any size" if b["bound"] is None else f"{b['bound']:.3g} {b['unit']}"
        why = b.get("note") or f"set by {b['set_by']}"
        at = f", {b['at']}" if b["at"] else ""
        lines.append(f"  - {b['effect']} {b['parameter']} on {b['where']}: {size} ({why}{at})")
    if doc.get("detection_bounds_not_covered"):
        lines.append(
            "  not bounded (no probe yet): " + ", ".join(doc["detection_bounds_not_covered"])
        )
    return lines


def report_text(doc: dict) -> str:
    """A one-page plain-text report of a diagnosis document."""
    u = doc["unit"]
    g = doc["goodness_of_fit"]
    lines = [
        f"encdesign diagnose: {doc.get('recording') or 'recording'} ({doc['kind']})",
        f"verdict: {doc['verdict']}",
        f"base model residual RMS: {doc['rms_before']:.4g} {u} fitted, "
        f"{doc['heldout_rms_before']:.4g} {u} held out ({doc['heldout']['k']} folds)",
        f"noise per channel: {', '.join(f'{s:.4g}' for s in doc['noise']['per_channel'])} {u}",
        f"goodness of fit: z = {g['statistic_z']:.2f}, p = {g['p_value']:.3g} "
        f"({'passes' if g['passes'] else 'fails'} at {g['alpha']})",
    ]
    if doc.get("excluded_share"):  # issue 22 item 4: prominent, near the top
        lines.insert(2, "WARNING: " + doc["excluded_share"]["note"])
    for what, run, t, detail in nuisance_rows(doc):
        lines.append(f"{what}: run {run} t {t} s: {detail}")
    for a in doc.get("angle_steps") or []:
        lines.append(
            f"angle step: channel {a['channel']} at {a['angle_rad']:.4g} rad, size "
            f"{a['size_rad']:.4g} rad, on {a['passes']} passes (of the angle, in the base)"
        )
    if (bo := doc.get("base_order")) is not None:  # issue 44 E: the base order's choice
        lines.append(
            f"base order: {bo['chosen']} (default {bo['start']}"
            + (", lowered by held-out error" if bo["lowered"] else "")
            + f"; held-out / fitted RMS {bo['heldout_ratio']:.3g} at {bo['start']})"
        )
        if len(bo["tried"]) > 1:
            lines.append(
                "  tried (order: fitted / held-out RMS): "
                + ", ".join(
                    f"{r['order']}: {r['rms']:.3g} / {r['heldout_rms']:.3g}" for r in bo["tried"]
                )
                + f" {u}"
            )
        if (ag := bo.get("again")) is not None:  # session 36: beside the named effects
            lines.append(
                f"  again beside {', '.join(ag['effects'])}: order {ag['chosen']}; held-out RMS "
                + ", ".join(f"{r['order']}: {r['heldout_rms']:.3g}" for r in ag["tried"])
                + f" {u}"
            )
    for f in doc["base"].get("fit_failures", []):  # issue 44 A: a stage that would diverge
        lines.append(f"fit failure ({f['stage']}): {f['cause']}; {f['recovery']}")
    if doc["base"]["unidentifiable"]:
        lines.append("unidentifiable from this recording:")
        lines += [f"  - {s}" for s in doc["base"]["unidentifiable"][:12]]
    for i, e in enumerate(doc["effects"], 1):
        col = e["collinearity"]
        col_s = "n/a" if col is None else f"{col:.3f}"
        dbic = "not fitted" if e["delta_bic"] is None else f"{e['delta_bic']:.1f}"
        lines.append(
            f"effect {i}: {e['name']} (dBIC {dbic}, "
            f"share {100 * e['share']:.0f}%, collinearity {col_s})"
        )
        ho = e["heldout_rms_after"]
        lines.append(
            f"  residual RMS -> {e['rms_after']:.4g} {u} fitted, "
            + ("n/a" if ho is None else f"{ho:.4g} {u}")
            + " held out"
        )
        if e["channels"] is not None:
            lines.append(f"  on channels: {e['channels']}")
        for name, p in e["params"].items():  # a parameter that is a time (issue 44 C)
            if isinstance(p, dict) and "interval_s" in p:
                lt = {"t_s": float(np.ravel(p["value"])[0]), **p}
                lines.append(f"  {name}: {describe_located(lt)} ({p['clock']})")
        lines.append(f"  {e['explanation']}")
        for n in e["notes"]:
            lines.append(f"  note: {n}")
    for r in doc["rejected"]:
        rnd = f"round {r['round']}" if r.get("round") is not None else "after selection"
        lines.append(f"rejected {r['name']} ({rnd}): {r['reason']}")
    for r in doc["not_testable"]:
        lines.append(f"not testable {r['name']}: {r['reason']}")
    for x in doc["unexplained"]:
        w = x["where"]
        loc = ", ".join(f"{k} {[round(v, 4) for v in w[k]][:6]}" for k in w if w[k])
        lines.append(f"unexplained ({x['view']}): {loc}; rms {x['rms']:.4g} {u}")
        if x.get("located_time"):
            lines.append(f"  located at {describe_located(x['located_time'])}")
        if x.get("step_at"):
            lines.append(f"  {x['step_at']['note']}")
        lines += _model_lines(x.get("model"), u)
    lines += bound_lines(doc)  # after what the record showed: what else it could have
    lines.append(f"status: {doc['status']}; {doc['time_s']:.1f} s")
    return "\n".join(lines) + "\n"
