"""Locate where a fitted model and a recording disagree (multihead kind).

Views of the residual ``r[n, H]`` (rad), each with a significance calibrated against white
read noise of standard deviation ``sigma_k`` per head (estimated from first differences, so
that slow structure does not inflate it), so that a recording with nothing missing yields
nothing:

* ``spectrum``: per run and head, periodogram in Hz (FFT, zero padded x4); peaks are
  expressed both in Hz and in shaft orders (``f / f_rev``). Across runs at different speeds
  a peak either stays fixed in Hz (a structural frequency) or in order (rotation-locked);
  fractional orders are resolved over the several revolutions of a run. Each peak also says
  how much of it is common to all heads (the head *sum*) and how much is in the head
  *differences*, and whether it cancels in the sums of opposed head pairs.
* ``repeatability``: per run and head, the residual binned by ``theta mod 2 pi``; a
  significant bin-mean profile is structure that repeats revolution after revolution.
* ``change_point``: per head, a step at one instant of the global time (runs laid end to
  end) in the order-1 terms (``sin``/``cos(theta - alpha_k)``) or in the offset.
* ``drift``: per head, correlation with ``temp_c - mean`` (and with time).
* ``line_phase``: per head, the residual folded by the phase within the grating pitch
  ``psi = L * reading`` (harmonics 1 and 2 of ``psi``): visible even when orders ``L`` and
  ``2L`` are aliased by coarse sampling.

Under white noise, the power a test with ``q`` regressors takes out of the residual, divided
by ``sigma^2``, is chi-square with ``q`` degrees of freedom. Each view tests at a
Bonferroni-corrected level ``alpha_view / n_tests``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from scipy import stats

ALPHA_VIEW = 1e-3
"""Family-wise false-alarm level of each view on a recording with nothing missing."""


@dataclasses.dataclass(frozen=True)
class LocateInput:
    """What the views need, all numpy, SI.

    Attributes:
        resid: residual ``(n, H)`` rad (head-mean removed per sample when there is no
            reference angle).
        run: run index ``0..R-1`` per sample.
        t: time within its run, s. tau: global time (runs end to end), s.
        theta: shaft angle, rad (unwrapped within each run).
        temp: ``temp_c`` per sample or ``None``.
        psi: line phase ``L * reading mod 2 pi`` ``(n, H)`` or ``None``.
        alpha: head azimuths, rad. sigma: noise std per head, rad.
        has_ref: whether ``theta_ref`` was recorded.
    """

    resid: np.ndarray
    run: np.ndarray
    t: np.ndarray
    tau: np.ndarray
    theta: np.ndarray
    temp: np.ndarray | None
    psi: np.ndarray | None
    alpha: np.ndarray
    sigma: np.ndarray
    has_ref: bool


@dataclasses.dataclass
class Finding:
    """One located mismatch.

    Attributes:
        view: ``spectrum``, ``repeatability``, ``change_point``, ``drift``, ``line_phase``.
        where: ``{orders, frequencies_hz, heads, runs, times_s}`` (lists).
        power: residual sum of squares it carries, rad^2.
        variance_share: ``power`` / total residual sum of squares.
        stat, dof, log10_p: chi-square statistic, its degrees of freedom, log10 p-value.
        detail: view-specific facts (``fixed_in``, ``integer_order``, ``common_share``, …).
        specs: regressor specifications, used to re-measure the same location later.
    """

    view: str
    where: dict[str, list]
    power: float
    variance_share: float
    stat: float
    dof: int
    log10_p: float
    detail: dict[str, Any]
    specs: list[tuple]

    def to_json(self) -> dict[str, Any]:
        """Plain-JSON form."""
        return {
            "view": self.view,
            "where": self.where,
            "rms": math.sqrt(self.power / max(self.detail.get("n_samples", 1), 1)),
            "variance_share": self.variance_share,
            "chi2": self.stat,
            "dof": self.dof,
            "log10_p": self.log10_p,
            **{k: v for k, v in self.detail.items() if k != "n_samples"},
        }


def noise_sigma(resid: np.ndarray, run: np.ndarray) -> np.ndarray:
    """Per-head white-noise std (rad), robust to structure.

    The periodogram of white noise of variance ``s^2`` is ``s^2`` times an exponential
    variable; its 30 % quantile is ``s^2 * -ln(0.7)``. A low quantile of every run's
    periodogram (mean removed, DC and Nyquist bins left out) is thus unbiased for noise and
    insensitive to narrow lines and to broadband structure filling up to about half the band.
    """
    out = []
    for k in range(resid.shape[1]):
        vals = []
        for r in np.unique(run):
            x = resid[run == r, k]
            if x.size < 8:
                continue
            x = x - x.mean()
            P = np.abs(np.fft.rfft(x)) ** 2 / x.size
            vals.append(P[1:-1])
        P = np.concatenate(vals) if vals else np.array([0.0])
        out.append(math.sqrt(float(np.quantile(P, 0.3)) / -math.log(0.7)))
    return np.maximum(np.asarray(out), 1e-15)


def _chi2_log10_sf(stat: float, dof: int) -> float:
    v = float(stats.chi2.logsf(stat, dof))
    if not math.isfinite(v):  # far tail: leading term of the asymptotic series
        x = 0.5 * stat
        v = -x + (0.5 * dof - 1.0) * math.log(max(x, 1e-300)) - math.lgamma(0.5 * dof)
    return v / math.log(10.0)


def _chi2_threshold(dof: int, n_tests: int, alpha: float = ALPHA_VIEW) -> float:
    return float(stats.chi2.isf(alpha / max(n_tests, 1), dof))


def _project_power(y: np.ndarray, x: np.ndarray) -> float:
    """Sum of squares of ``y`` explained by the columns of ``x`` (least squares)."""
    if x.size == 0:
        return 0.0
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    fit = x @ coef
    return float(fit @ fit)


def _regressors(spec: tuple, inp: LocateInput) -> tuple[np.ndarray, np.ndarray, int]:
    """Rows, regressor matrix and head for one location spec."""
    kind = spec[0]
    if kind == "sinusoid":  # run, head, f_hz
        _, r, k, f = spec
        rows = np.flatnonzero(inp.run == r)
        w = 2 * np.pi * f * inp.t[rows]
        return rows, np.stack([np.cos(w), np.sin(w)], 1), k
    if kind == "sync":  # run, head, n_bins
        _, r, k, nb = spec
        rows = np.flatnonzero(inp.run == r)
        b = np.floor(np.mod(inp.theta[rows], 2 * np.pi) / (2 * np.pi) * nb).astype(int)
        x = np.zeros((rows.size, nb))
        x[np.arange(rows.size), np.clip(b, 0, nb - 1)] = 1.0
        x -= x.mean(0)
        return rows, x, k
    if kind in ("step_order1", "step_offset"):  # head, tau_s
        _, k, ts = spec
        rows = np.arange(inp.resid.shape[0])
        s = (inp.tau >= ts).astype(float)
        if kind == "step_offset":
            return rows, (s - s.mean())[:, None], k
        d = inp.theta - inp.alpha[k]
        return rows, np.stack([s * np.sin(d), s * np.cos(d)], 1), k
    if kind == "drift":  # head, driver name
        _, k, drv = spec
        rows = np.arange(inp.resid.shape[0])
        v = inp.temp if drv == "temp_c" else inp.tau
        return rows, (v - v.mean())[:, None], k
    if kind == "line_phase":  # head, runs
        _, k, runs = spec
        rows = np.flatnonzero(np.isin(inp.run, runs))
        p = inp.psi[rows, k]
        x = np.stack([np.cos(p), np.sin(p), np.cos(2 * p), np.sin(2 * p)], 1)
        return rows, x, k
    raise ValueError(spec)


def spec_power(spec: tuple, inp: LocateInput, resid: np.ndarray | None = None) -> float:
    """Residual power (rad^2) at one location spec (re-measured on ``resid`` if given)."""
    r = inp.resid if resid is None else resid
    rows, x, k = _regressors(spec, inp)
    y = r[rows, k]
    return _project_power(y - y.mean(), x)


def finding_power(f: Finding, inp: LocateInput, resid: np.ndarray) -> float:
    """Power now left at the location of finding ``f`` (rad^2)."""
    return float(sum(spec_power(s, inp, resid) for s in f.specs))


# ----------------------------------------------------------------------------- views


def _run_info(inp: LocateInput):
    out = []
    for r in np.unique(inp.run):
        rows = np.flatnonzero(inp.run == r)
        t = inp.t[rows]
        th = inp.theta[rows]
        dur = t[-1] - t[0]
        revs = abs(th[-1] - th[0]) / (2 * np.pi)
        f_rev = revs / dur if dur > 0 else 0.0
        out.append((int(r), rows, t, dur, revs, f_rev))
    return out


def _spectrum_view(inp: LocateInput, total_ss: float) -> list[Finding]:
    H = inp.resid.shape[1]
    runs = _run_info(inp)
    n_tests = sum(max(rows.size // 2, 1) for _, rows, *_ in runs) * H
    thr = _chi2_threshold(2, n_tests)
    relaxed = _chi2_threshold(2, 2 * max(len(runs), 1) * H, alpha=0.01)
    peaks = []  # (run, f_hz, order, heads, power, stat)
    for r, rows, t, dur, revs, f_rev in runs:
        n = rows.size
        if n < 16 or dur <= 0:
            continue
        dt = dur / (n - 1)
        tu = t[0] + dt * np.arange(n)
        res = inp.resid[rows]
        if np.max(np.abs(np.diff(t) - dt)) > 0.01 * dt:
            res = np.stack([np.interp(tu, t, res[:, k]) for k in range(H)], 1)
        res = res - res.mean(0)
        pad = 4
        spec = np.fft.rfft(res, n=pad * n, axis=0)
        freqs = np.fft.rfftfreq(pad * n, dt)
        pstat = (np.abs(spec) ** 2) * 2.0 / (n * inp.sigma[None, :] ** 2)
        fmin = 2.0 / dur
        ok = freqs >= fmin
        ok[-pad:] = False
        tot = pstat.max(1)
        cand = np.flatnonzero(ok[1:-1] & (tot[1:-1] > thr)) + 1
        cand = [i for i in cand if tot[i] >= tot[i - 1] and tot[i] >= tot[i + 1]]
        cand.sort(key=lambda i: -tot[i])
        taken: list[float] = []
        for i in cand[:8]:
            f0 = freqs[i]
            if any(abs(f0 - g) < 3.0 / dur for g in taken):
                continue
            taken.append(f0)
            # parabolic refinement on the strongest head
            k0 = int(np.argmax(pstat[i]))
            y0, y1, y2 = pstat[i - 1, k0], pstat[i, k0], pstat[i + 1, k0]
            den = y0 - 2 * y1 + y2
            off = 0.5 * (y0 - y2) / den if den != 0 else 0.0
            f = f0 + float(np.clip(off, -0.5, 0.5)) * (freqs[1] - freqs[0])
            heads = [k for k in range(H) if pstat[i, k] > relaxed]
            X = spec[i]
            common = float(H * abs(X.mean()) ** 2 / max(np.sum(np.abs(X) ** 2), 1e-300))
            pw = [spec_power(("sinusoid", r, k, f), inp) for k in range(H)]
            st = [p / inp.sigma[k] ** 2 for k, p in enumerate(pw)]
            peaks.append(
                dict(
                    run=r,
                    f=f,
                    order=f / f_rev if f_rev > 0 else float("nan"),
                    heads=[k for k in range(H) if st[k] > relaxed] or heads,
                    powers=pw,
                    stat=max(st),
                    f_rev=f_rev,
                    dur=dur,
                    revs=revs,
                    common=common,
                    pair=_opposed_pair_share(X, inp.alpha),
                )
            )
    return _group_peaks(peaks, runs, inp, total_ss, thr, relaxed)


def _opposed_pair_share(X: np.ndarray, alpha: np.ndarray) -> float | None:
    """|X_i + X_j|^2 / (|X_i|^2 + |X_j|^2) / 2 averaged over opposed head pairs (None if none)."""
    vals = []
    H = alpha.size
    for i in range(H):
        for j in range(i + 1, H):
            d = np.mod(alpha[j] - alpha[i], 2 * np.pi)
            if abs(d - np.pi) < np.deg2rad(2.0):
                den = abs(X[i]) ** 2 + abs(X[j]) ** 2
                if den > 0:
                    vals.append(abs(X[i] + X[j]) ** 2 / (2 * den))
    return float(np.mean(vals)) if vals else None


def _group_peaks(peaks, runs, inp, total_ss, thr, relaxed) -> list[Finding]:
    H = inp.resid.shape[1]
    used = [False] * len(peaks)
    order_idx = sorted(range(len(peaks)), key=lambda i: -peaks[i]["stat"])
    findings = []
    for i in order_idx:
        if used[i]:
            continue
        p = peaks[i]
        used[i] = True
        members = [p]
        by_hz = by_order = 0
        for j in order_idx:
            q = peaks[j]
            if used[j] or q["run"] == p["run"]:
                continue
            tol_hz = 1.5 / min(p["dur"], q["dur"])
            tol_o = 1.5 / max(min(p["revs"], q["revs"]), 1e-9)
            same_hz = abs(q["f"] - p["f"]) < tol_hz
            same_o = abs(q["order"] - p["order"]) < tol_o
            if same_hz or same_o:
                used[j] = True
                members.append(q)
                by_hz += same_hz and not same_o
                by_order += same_o and not same_hz
        # runs without a peak: compare the evidence at the same Hz and at the same order
        seen = {m["run"] for m in members}
        ev_hz = ev_o = 0.0
        distinct_speed = False
        for r, _rows, _t, dur, _revs, f_rev in runs:
            if r in seen or f_rev <= 0:
                continue
            fo = p["order"] * f_rev
            if abs(fo - p["f"]) > 1.5 / dur:
                distinct_speed = True
            ev_hz += max(
                spec_power(("sinusoid", r, k, p["f"]), inp) / inp.sigma[k] ** 2 for k in range(H)
            )
            ev_o += max(
                spec_power(("sinusoid", r, k, fo), inp) / inp.sigma[k] ** 2 for k in range(H)
            )
        for m in members[1:]:
            if abs(m["order"] * p["f_rev"] - p["f"]) > 1.5 / min(m["dur"], p["dur"]):
                distinct_speed = True
            if abs(m["f_rev"] - p["f_rev"]) > 1.5 / min(m["dur"], p["dur"]):
                distinct_speed = True
        if by_hz > by_order or (distinct_speed and ev_hz > relaxed and ev_hz > 4 * ev_o):
            fixed_in = "hz"
        elif by_order > by_hz or (distinct_speed and ev_o > relaxed and ev_o > 4 * ev_hz):
            fixed_in = "order"
        elif distinct_speed and len(members) == 1:
            fixed_in = "single_run"
        else:
            fixed_in = "undetermined"
        orders = [m["order"] for m in members]
        tol_int = [0.6 / max(m["revs"], 1e-9) + 0.02 for m in members]
        integer = all(abs(o - round(o)) < tl for o, tl in zip(orders, tol_int)) and all(
            round(o) >= 1 for o in orders
        )
        specs = [("sinusoid", m["run"], k, m["f"]) for m in members for k in range(H)]
        power = float(sum(sum(m["powers"]) for m in members))
        heads = sorted({k for m in members for k in m["heads"]})
        stat = float(max(m["stat"] for m in members))
        if stat <= thr:
            continue
        pair = [m["pair"] for m in members if m["pair"] is not None]
        findings.append(
            Finding(
                view="spectrum",
                where=dict(
                    orders=[float(o) for o in orders],
                    frequencies_hz=[float(m["f"]) for m in members],
                    heads=heads,
                    runs=[m["run"] for m in members],
                    times_s=[],
                ),
                power=power,
                variance_share=power / total_ss,
                stat=stat,
                dof=2,
                log10_p=_chi2_log10_sf(stat, 2),
                detail=dict(
                    fixed_in=fixed_in,
                    integer_order=bool(integer),
                    common_share=float(np.mean([m["common"] for m in members])),
                    opposed_pair_sum_share=float(np.mean(pair)) if pair else None,
                    n_samples=sum(int(np.sum(inp.run == m["run"])) for m in members) * H,
                ),
                specs=specs,
            )
        )
    return findings


def _repeatability_view(inp: LocateInput, total_ss: float) -> list[Finding]:
    H = inp.resid.shape[1]
    runs = _run_info(inp)
    out = []
    n_tests = len(runs) * H
    for r, rows, _t, _dur, revs, _f_rev in runs:
        if revs < 2.5:
            continue
        spr = rows.size / revs
        nb = int(min(64, max(8, spr // 4)))
        thr = _chi2_threshold(nb - 1, n_tests)
        for k in range(H):
            spec = ("sync", r, k, nb)
            pw = spec_power(spec, inp)
            st = pw / inp.sigma[k] ** 2
            if st > thr:
                out.append(
                    Finding(
                        view="repeatability",
                        where=dict(orders=[], frequencies_hz=[], heads=[k], runs=[r], times_s=[]),
                        power=pw,
                        variance_share=pw / total_ss,
                        stat=st,
                        dof=nb - 1,
                        log10_p=_chi2_log10_sf(st, nb - 1),
                        detail=dict(
                            n_bins=nb,
                            repeatable_share=pw
                            / max(float(np.sum(inp.resid[rows, k] ** 2)), 1e-300),
                            n_samples=int(rows.size),
                        ),
                        specs=[spec],
                    )
                )
    return _merge_by(out, "runs", total_ss)


def _merge_by(findings: list[Finding], key: str, total_ss: float) -> list[Finding]:
    """Merge findings of one view whose ``where[key]`` coincide (heads pooled)."""
    groups: dict[tuple, list[Finding]] = {}
    for f in findings:
        groups.setdefault(tuple(f.where[key]), []).append(f)
    out = []
    for fs in groups.values():
        f0 = max(fs, key=lambda f: f.stat)
        heads = sorted({h for f in fs for h in f.where["heads"]})
        power = sum(f.power for f in fs)
        where = dict(f0.where, heads=heads)
        detail = dict(f0.detail, n_samples=sum(f.detail.get("n_samples", 1) for f in fs))
        out.append(
            Finding(
                view=f0.view,
                where=where,
                power=power,
                variance_share=power / total_ss,
                stat=f0.stat,
                dof=f0.dof,
                log10_p=f0.log10_p,
                detail=detail,
                specs=[s for f in fs for s in f.specs],
            )
        )
    return out


def _tau_to_run_time(inp: LocateInput, ts: float) -> tuple[int, float]:
    i = int(np.clip(np.searchsorted(inp.tau, ts), 0, inp.tau.size - 1))
    return int(inp.run[i]), float(inp.t[i])


def _change_point_view(inp: LocateInput, total_ss: float) -> list[Finding]:
    n, H = inp.resid.shape
    G = int(min(n, 400))
    lo, hi = int(0.02 * n), int(0.98 * n)
    grid = np.unique(np.linspace(lo, hi, G).astype(int))
    out = []
    for kind, dof in (("step_order1", 2), ("step_offset", 1)):
        thr = _chi2_threshold(dof, grid.size * H * 2)
        for k in range(H):
            y = inp.resid[:, k] - inp.resid[:, k].mean()
            if kind == "step_offset":
                ca = np.cumsum(y[::-1])[::-1]
                na = n - np.arange(n)
                var = na * (1 - na / n)
                st_all = ca[grid] ** 2 / np.maximum(var[grid], 1e-300) / inp.sigma[k] ** 2
            else:
                d = inp.theta - inp.alpha[k]
                s, c = np.sin(d), np.cos(d)
                rc = lambda v: np.cumsum(v[::-1])[::-1]
                ys, yc, ss, cc, sc = rc(y * s), rc(y * c), rc(s * s), rc(c * c), rc(s * c)
                a11, a22, a12 = ss[grid], cc[grid], sc[grid]
                b1, b2 = ys[grid], yc[grid]
                det = a11 * a22 - a12**2
                det = np.where(np.abs(det) > 1e-300, det, 1e-300)
                st_all = (a22 * b1**2 - 2 * a12 * b1 * b2 + a11 * b2**2) / det
                st_all = st_all / inp.sigma[k] ** 2
            j = int(np.argmax(st_all))
            st = float(st_all[j])
            if st > thr:
                ts = float(inp.tau[grid[j]])
                spec = (kind, k, ts)
                pw = spec_power(spec, inp)
                r, tr = _tau_to_run_time(inp, ts)
                out.append(
                    Finding(
                        view="change_point",
                        where=dict(
                            orders=[1.0] if kind == "step_order1" else [0.0],
                            frequencies_hz=[],
                            heads=[k],
                            runs=[r],
                            times_s=[tr],
                        ),
                        power=pw,
                        variance_share=pw / total_ss,
                        stat=st,
                        dof=dof,
                        log10_p=_chi2_log10_sf(st, dof),
                        detail=dict(step=kind, global_time_s=ts, n_samples=n),
                        specs=[spec],
                    )
                )
    # merge heads that change at about the same instant (within 2 % of the record)
    span = float(inp.tau[-1] - inp.tau[0]) or 1.0
    merged: list[Finding] = []
    for f in sorted(out, key=lambda f: -f.stat):
        for g in merged:
            if (
                g.detail["step"] == f.detail["step"]
                and abs(g.detail["global_time_s"] - f.detail["global_time_s"]) < 0.02 * span
            ):
                g.where["heads"] = sorted(set(g.where["heads"]) | set(f.where["heads"]))
                g.power += f.power
                g.variance_share = g.power / total_ss
                g.specs.append((f.specs[0][0], f.specs[0][1], g.detail["global_time_s"]))
                break
        else:
            merged.append(f)
    return merged


def _drift_view(inp: LocateInput, total_ss: float) -> list[Finding]:
    n, H = inp.resid.shape
    drivers = ["time"] + (["temp_c"] if inp.temp is not None and np.ptp(inp.temp) > 0 else [])
    thr = _chi2_threshold(1, H * len(drivers))
    out = []
    for drv in drivers:
        for k in range(H):
            spec = ("drift", k, drv)
            pw = spec_power(spec, inp)
            st = pw / inp.sigma[k] ** 2
            if st > thr:
                v = inp.temp if drv == "temp_c" else inp.tau
                corr = float(np.corrcoef(v, inp.resid[:, k])[0, 1])
                out.append(
                    Finding(
                        view="drift",
                        where=dict(orders=[], frequencies_hz=[], heads=[k], runs=[], times_s=[]),
                        power=pw,
                        variance_share=pw / total_ss,
                        stat=st,
                        dof=1,
                        log10_p=_chi2_log10_sf(st, 1),
                        detail=dict(driver=drv, correlation=corr, n_samples=n),
                        specs=[spec],
                    )
                )
    groups: dict[str, list[Finding]] = {}
    for f in out:
        groups.setdefault(f.detail["driver"], []).append(f)
    res = []
    for fs in groups.values():
        res.extend(_merge_by(fs, "runs", total_ss))
    return res


def line_phase_runs(psi: np.ndarray, run: np.ndarray, limit: float = 0.3) -> list[int]:
    """Runs in which the line phase ``psi`` sweeps the pitch evenly (circular means of
    ``exp(i psi)`` and ``exp(2 i psi)`` below ``limit``). Where it does not (a speed that
    advances a whole number of lines per sample) a pitch-periodic error is aliased to a
    constant and cannot be told from an offset."""
    out = []
    for r in np.unique(run):
        p = psi[run == r]
        if max(abs(np.mean(np.exp(1j * p))), abs(np.mean(np.exp(2j * p)))) < limit:
            out.append(int(r))
    return out


def _line_phase_view(inp: LocateInput, total_ss: float) -> list[Finding]:
    if inp.psi is None:
        return []
    n, H = inp.resid.shape
    thr = _chi2_threshold(4, H)
    out = []
    for k in range(H):
        runs = line_phase_runs(inp.psi[:, k], inp.run)
        if not runs:
            continue
        spec = ("line_phase", k, tuple(runs))
        pw = spec_power(spec, inp)
        st = pw / inp.sigma[k] ** 2
        if st > thr:
            out.append(
                Finding(
                    view="line_phase",
                    where=dict(orders=[], frequencies_hz=[], heads=[k], runs=[], times_s=[]),
                    power=pw,
                    variance_share=pw / total_ss,
                    stat=st,
                    dof=4,
                    log10_p=_chi2_log10_sf(st, 4),
                    detail=dict(n_samples=n),
                    specs=[spec],
                )
            )
    return _merge_by(out, "runs", total_ss)


def locate(inp: LocateInput, *, line_orders: tuple[int, ...] = ()) -> list[Finding]:
    """Run every view on ``inp.resid``; return the significant findings, strongest first.

    Args:
        inp: the residual and its coordinates (see :class:`LocateInput`).
        line_orders: orders ``L``, ``2L`` to name in ``line_phase`` findings.
    """
    total_ss = max(float(np.sum(inp.resid**2)), 1e-300)
    out = (
        _spectrum_view(inp, total_ss)
        + _repeatability_view(inp, total_ss)
        + _change_point_view(inp, total_ss)
        + _drift_view(inp, total_ss)
        + _line_phase_view(inp, total_ss)
    )
    for f in out:
        if f.view == "line_phase":
            f.where["orders"] = [float(o) for o in line_orders]
    out.sort(key=lambda f: -f.power)
    return out
