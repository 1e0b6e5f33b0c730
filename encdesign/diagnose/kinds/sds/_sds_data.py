"""The SDS kind's data: the pair table from the stamps, the stamp lattice, the kind data and
the prepared record (one row per run)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from ...._errors import input_error
from ....io._recording import Recording
from ...engine._candidates import Context
from ...engine._protocol import KindData, Prepared, RowColumns
from ...engine._settings import DEFAULT_SETTINGS, FinderSettings
from ._sds_clock_lock import clock_lock_share, rounding_common_excess
from ._sds_noise import (
    REFERENCE_RADIUS_M,
    design_orders,
    run_mean_levels,
)

# ----------------------------------------------------------------------------- data


@dataclasses.dataclass(frozen=True)
class SDSPairTable:
    """Shifted delta sums per run, revolution and sensor pair, from an ``sds`` recording.

    Attributes:
        run_ids: run ids of the table, shape (P,).
        phi_ref_rad: reference platform angle per run, rad, or ``None``.
        phi_meas_rad: measured platform angle per run (mean of its pair readings), rad.
        run, rev, fixed, moving: per datum: run index 0…P−1, revolution within the run,
            fixed and moving sensor index; shape (n,).
        t_mid_s: mid-time of the datum's revolution window (from the anchor edge), s.
        t_fixed_s, t_moving_s: mean time of the fixed and of the moving sensor's window
            (the windows of sensors whose edges start late are shifted), s.
        value_rad: the pair's SDS reading of φ, rad, wrapped to (−π, π].
        psi_fixed_rad, psi_moving_rad: nominal sensor azimuths (TOML), rad.
        period_s: mean revolution time, s.
        n_marks: marks per revolution.
        run_clock_s: per run ``(first edge time, revolution time)`` of sensor f0, s, shape
            (P, 2) (:func:`_run_clock`).
    """

    run_ids: np.ndarray
    phi_ref_rad: np.ndarray | None
    phi_meas_rad: np.ndarray
    run: np.ndarray
    rev: np.ndarray
    fixed: np.ndarray
    moving: np.ndarray
    t_mid_s: np.ndarray
    t_fixed_s: np.ndarray
    t_moving_s: np.ndarray
    value_rad: np.ndarray
    psi_fixed_rad: np.ndarray
    psi_moving_rad: np.ndarray
    period_s: float
    n_marks: int
    run_clock_s: np.ndarray | None = None


def _wrap(x):
    return np.mod(np.asarray(x) + np.pi, 2 * np.pi) - np.pi


def _split_runs(rec: Recording):
    from ....io._sds_format import check_sds_columns
    from ....io._sds_format import sensor_counts as _sensor_counts

    where = str(rec.path) if rec.path is not None else "<recording>"
    if rec.kind != "sds":
        raise input_error(where, f"kind {rec.kind!r}", "a recording of kind 'sds'")
    check_sds_columns(where, rec.meta, rec.columns)
    n_marks, nf, nm = _sensor_counts(rec.meta)
    cols = rec.columns
    run = rec.runs
    names = [f"f{i}" for i in range(nf)] + [f"m{i}" for i in range(nm)]
    out = []
    for r in np.unique(run):
        sel = run == r
        sens, mk, t = cols["sensor"][sel], cols["mark"][sel], cols["t"][sel]
        times, marks = {}, {}
        for name in names:
            s = sens == name
            if not np.any(s):
                raise input_error(f"{where}, run {int(r)}", f"no edges of sensor {name}")
            times[name], marks[name] = t[s], mk[s]
        ref = float(cols["phi_ref"][sel][0]) if "phi_ref" in cols else None
        out.append((int(r), times, marks, ref))
    return where, n_marks, nf, nm, out


def _run_clock(times: np.ndarray, marks: np.ndarray, n_marks: int) -> tuple[float, float]:
    """``(first edge time, revolution time)`` (s) of one sensor's edges in one run: the time
    from each edge to the same mark's edge one revolution on, averaged over the run's edges
    (the marks' and the motor's once-per-revolution patterns cancel in each difference; a
    line through the stamps against the edge count does not cancel them: 7 ticks off at
    six revolutions). Over a few thousand edges the stamps' rounding and jitter average to
    a few thousandths of a clock tick, which :func:`._sds_clock_lock.clock_lock_share` needs; one
    revolution's window (``period_s``) is known to a few tenths of a tick only. Revolution
    time 0 where the edges are not consecutive marks for more than a revolution."""
    t = np.asarray(times, float)
    step = np.mod(np.diff(np.asarray(marks, np.int64)), n_marks)
    if t.size <= n_marks or np.any(step != 1):
        return (float(t[0]) if t.size else 0.0, 0.0)
    return float(t[0]), float(np.mean(t[n_marks:] - t[:-n_marks]))


def sds_pair_table(rec: Recording) -> SDSPairTable:
    """Per-pair, per-revolution SDS readings and window mid-times of an ``sds`` recording.

    Raises:
        EncdesignInputError: not an ``sds`` recording, malformed table, a run without a
            complete revolution for every sensor.
    """
    from ._sds_readout import run_windows as _run_windows
    from ._sds_readout import sds_jit as _sds_jit

    where, n_marks, nf, nm, runs = _split_runs(rec)
    enc = rec.encoder
    psi_f = np.radians(np.asarray(enc["fixed_sensor_angles_deg"], dtype=float))
    psi_m = np.radians(np.asarray(enc["moving_sensor_angles_deg"], dtype=float))
    offsets = jnp.asarray(psi_m[None, :] - psi_f[:, None])
    acc: dict[str, list] = {k: [] for k in ("run", "rev", "f", "m", "t", "tf", "tm", "v")}
    refs, meas, periods, clocks = [], [], [], []
    for i, (r, times, marks, ref) in enumerate(runs):
        clocks.append(_run_clock(times["f0"], marks["f0"], n_marks))
        alpha, period, k_f, tau, k_m = _run_windows(where, r, times, marks, n_marks, nf, nm)
        # a reading needs every window to start at the anchor (within two mark spacings):
        # a sensor whose edges begin later in the record gives a shifted window
        anchor = alpha[:, 0, :].min(axis=1)
        starts = np.concatenate([alpha.min(axis=2), tau.min(axis=2)], axis=1)
        good = np.all(starts - anchor[:, None] < 2 * period[:, :1] / n_marks, axis=1)
        if not np.any(good):
            raise input_error(
                f"{where}, run {r}",
                "no revolution in which every sensor's edges start at the f0 mark-0 edge",
                "every sensor recorded from (before) the first complete revolution",
            )
        alpha, period, k_f, tau, k_m = (a[good] for a in (alpha, period, k_f, tau, k_m))
        pair = np.asarray(_sds_jit(alpha, period, k_f, tau, k_m, offsets))  # (R, F, M)
        if not np.all(np.isfinite(pair)):
            raise input_error(f"{where}, run {r}", "non-finite SDS result", "finite times")
        n_rev = pair.shape[0]
        t_mid = alpha[:, 0, :].min(axis=1) + period[:, 0] / 2
        t_fix = alpha.mean(axis=2)  # (R, F): mean time of each window (the SDS averages it)
        t_mov = tau.mean(axis=2)  # (R, M)
        first = pair.reshape(-1)[0]
        centre = _wrap(first + np.mean(_wrap(pair - first)))
        meas.append(float(centre))
        refs.append(ref)
        periods.append(period.mean())
        rr, ff, mm = np.meshgrid(np.arange(n_rev), np.arange(nf), np.arange(nm), indexing="ij")
        acc["run"].append(np.full(pair.size, i))
        acc["rev"].append(rr.ravel())
        acc["f"].append(ff.ravel())
        acc["m"].append(mm.ravel())
        acc["t"].append(np.repeat(t_mid, nf * nm))
        acc["tf"].append(np.broadcast_to(t_fix[:, :, None], pair.shape).ravel())
        acc["tm"].append(np.broadcast_to(t_mov[:, None, :], pair.shape).ravel())
        acc["v"].append(_wrap(pair.ravel()))
    has_ref = all(x is not None for x in refs)
    return SDSPairTable(
        run_ids=np.asarray([r[0] for r in runs]),
        phi_ref_rad=np.asarray(refs, dtype=float) if has_ref else None,
        phi_meas_rad=np.asarray(meas),
        run=np.concatenate(acc["run"]),
        rev=np.concatenate(acc["rev"]),
        fixed=np.concatenate(acc["f"]),
        moving=np.concatenate(acc["m"]),
        t_mid_s=np.concatenate(acc["t"]),
        t_fixed_s=np.concatenate(acc["tf"]),
        t_moving_s=np.concatenate(acc["tm"]),
        value_rad=np.concatenate(acc["v"]),
        psi_fixed_rad=psi_f,
        psi_moving_rad=psi_m,
        period_s=float(np.mean(periods)),
        n_marks=n_marks,
        run_clock_s=np.asarray(clocks, float),
    )


def sds_speed_harmonics(
    rec: Recording, phi_rad: np.ndarray | None = None, max_order: int | None = None
) -> dict[str, np.ndarray]:
    """Shaft speed harmonics from the moving sensors' edge intervals.

    The interval from mark j to j+1 at moving sensor m in run r is ``Δμ_j / ω``: its log is
    ``log Δμ_j − Re(E_n e^{i n θ})`` with ``θ = φ_r + ψ_m + 2π(j+½)/N`` and ``E_n = ε^c_n −
    i ε^s_n`` the relative speed ripple. Per order n the DFT over marks of the mean log
    interval is ``L_n − (E_n/2) e^{i n (φ_r+ψ_m)}``; a complex regression over runs and
    sensors separates the mark spacing ``L_n`` (disk B, common) from ``E_n``.

    Args:
        rec: an ``sds`` recording.
        phi_rad: platform angle per run (default ``phi_ref`` or the measured φ), rad.
        max_order: highest order (default ``min(N/4, 100)``).

    Returns:
        ``orders``, ``amplitude`` (relative speed ripple |E_n|), ``stderr`` (of it),
        ``chi2`` (|Ê_n|² over its variance: χ²₂ under no ripple), ``cos``, ``sin``
        (ε^c_n, ε^s_n, relative to disk B's index).
    """
    where, n_marks, nf, nm, runs = _split_runs(rec)
    enc = rec.encoder
    psi_m = np.radians(np.asarray(enc["moving_sensor_angles_deg"], dtype=float))
    if phi_rad is None:
        phi_rad = sds_pair_table(rec).phi_meas_rad
        if runs[0][3] is not None:
            phi_rad = np.asarray([r[3] for r in runs])
    max_order = int(min(n_marks // 4, 100) if max_order is None else max_order)
    rows, angles = [], []
    for i, (_, times, marks, _) in enumerate(runs):
        for m in range(nm):
            t, mk = times[f"m{m}"], marks[f"m{m}"]
            d = np.diff(t)
            j = mk[:-1]
            ok = np.mod(mk[1:] - j, n_marks) == 1
            s = np.bincount(j[ok], weights=np.log(d[ok]), minlength=n_marks)
            c = np.bincount(j[ok], minlength=n_marks)
            if np.any(c == 0):
                raise input_error(f"{where}, run {runs[i][0]}", "a mark interval never seen")
            rows.append(s / c)
            angles.append(phi_rad[i] + psi_m[m])
    y = np.asarray(rows)  # (K, N)
    a = np.asarray(angles)
    b = 2 * np.pi * (np.arange(n_marks) + 0.5) / n_marks
    orders = np.arange(1, max_order + 1)
    Y = (y - y.mean(axis=1, keepdims=True)) @ np.exp(-1j * np.outer(b, orders)) / n_marks
    amp, se, chi2, ec, es = [], [], [], [], []
    k = len(a)
    for i, n in enumerate(orders):
        X = np.column_stack([np.ones(k), np.exp(1j * n * a)])
        coef, *_ = np.linalg.lstsq(X, Y[:, i], rcond=None)
        res = Y[:, i] - X @ coef
        dof = max(k - 2, 1)
        s2 = float(np.sum(np.abs(res) ** 2)) / dof  # complex variance
        cov = s2 * np.linalg.pinv(X.conj().T @ X)
        e = -2 * coef[1]
        var_e = 4 * float(np.real(cov[1, 1]))
        amp.append(abs(e))
        se.append(math.sqrt(var_e / 2))
        chi2.append(2 * abs(e) ** 2 / max(var_e, 1e-300))
        ec.append(float(np.real(e)))
        es.append(float(-np.imag(e)))
    return {
        "orders": orders,
        "amplitude": np.asarray(amp),
        "stderr": np.asarray(se),
        "chi2": np.asarray(chi2),
        "cos": np.asarray(ec),
        "sin": np.asarray(es),
        "n_samples": k,
    }


def stamp_lattice(
    t: np.ndarray, max_samples: int = 200_000, settings: FinderSettings = DEFAULT_SETTINGS
) -> dict[str, Any]:
    """The lattice the time stamps lie on, found from the data (any clock).

    Stamps on a clock of period ``P`` (and any offset) are ``t = t0 + n P``: the differences of
    consecutive stamps are integer multiples of ``P`` and their distinct values are spaced by
    multiples of ``P``. The candidate ``P`` is the smallest gap between distinct differences
    (gaps below 1e-6 of the median difference are floating-point noise of the file, merged;
    the median and lower quantiles of the gaps too, as a few stray stamps make odd gaps),
    divided by 1 ... 10; the coarsest that puts the differences within 2 % of ``P`` of a
    multiple of it (at most 0.5 % of them may miss: stray stamps) wins. ``None`` when no
    lattice coarser than 1e-6 of the median difference explains the stamps (free-running,
    continuous times).

    Returns:
        ``period_s`` (or ``None``), ``fraction_on_lattice``, ``n_differences``, ``method``.
    """
    t = np.asarray(t, dtype=float)
    d = np.diff(np.sort(t))
    d = d[d > 0]
    if d.size > max_samples:
        d = d[:: d.size // max_samples]
    out: dict[str, Any] = {
        "period_s": None,
        "fraction_on_lattice": None,
        "n_differences": int(d.size),
        "method": "gaps between distinct stamp differences (quantiles 0-0.5) divided by "
        "1..10; the coarsest period with >= 99.5 % of the differences within 2 % of a "
        "multiple wins",
    }
    if d.size < 16:
        return out
    med = float(np.median(d))
    floor = 1e-6 * med
    u = np.unique(d)
    gaps = np.diff(u)
    # merge float noise: distinct values closer than the floor are one value
    gaps = gaps[gaps > floor]
    # candidates: gaps between distinct differences at several quantiles (a few stray
    # stamps make odd small gaps; the lattice makes most gaps one period), each divided by
    # 1..10; the coarsest period that fits wins
    base = {float(u[0])}
    if gaps.size:
        base |= {float(np.quantile(gaps, q)) for q in (0.5, 0.25, 0.1, 0.0)}
    cands = sorted({b / k for b in base for k in range(1, 11) if b / k > floor}, reverse=True)
    for p in cands:
        q = d / p
        n = np.round(q)
        on = np.abs(q - n) < settings.sds_lattice_tol
        frac = float(np.mean(on))
        if frac >= settings.sds_lattice_share:
            # refine the period from the integer multiples (least squares through 0)
            p = float(np.sum(n[on] * d[on]) / np.sum(n[on] * n[on]))
            out.update(period_s=p, fraction_on_lattice=frac)
            return out
    return out


def _helmert(K: int) -> np.ndarray:
    """Row 0: the mean (weights 1/K); rows 1..K-1: orthonormal contrasts."""
    H = np.zeros((K, K))
    H[0] = 1.0 / K
    for k in range(1, K):
        H[k, :k] = 1.0
        H[k, k] = -k
        H[k] /= math.sqrt(k * (k + 1))
    return H


@dataclasses.dataclass
class SDSKindData(KindData):
    """:class:`~encdesign.diagnose.engine._protocol.KindData` plus the SDS pair table and clock."""

    table: Any = None
    n_revs: int = 0
    lattice: dict | None = None
    declared_clock_s: float | None = None
    rows_extra: dict | None = None
    dropped_revs: int = 0
    speed: dict | None = None


def lattice_floor(kd: SDSKindData) -> tuple[float | None, float | None]:
    """``(ratio, floor)``: the stamps' lattice period over the declared clock period (``None``
    without a lattice or a declared clock) and the quantization floor of one pair reading on
    that lattice, rad (``None`` without a lattice): a uniform stamp error (variance
    ``P^2 / 12``) on the ``2 N`` window edges of a pair, ``2 pi P / (T sqrt(6 N))`` with ``P``
    the lattice period, ``T`` the revolution time and ``N`` the marks (seed 001 eq. 23)."""
    P = (kd.lattice or {}).get("period_s")
    if P is None:
        return None, None
    T, N = kd.table.period_s, kd.table.n_marks
    floor = 2 * math.pi * P / (T * math.sqrt(6 * N))
    return (P / kd.declared_clock_s if kd.declared_clock_s else None), floor


def sds_data(rec: Recording, settings: FinderSettings = DEFAULT_SETTINGS) -> SDSKindData:
    """Rows (runs) and channels (moving sensor × {run mean, revolution contrasts});
    ``settings``: the time-stamp lattice thresholds."""
    tab = sds_pair_table(rec)
    where = str(rec.path) if rec.path is not None else "recording"
    R = tab.run_ids.size
    F, M = tab.psi_fixed_rad.size, tab.psi_moving_rad.size
    if R < 4:
        raise input_error(where, f"{R} runs (platform positions)", "at least 4 runs")
    counts = np.bincount(tab.run, minlength=R) // (F * M)
    K = int(counts.min())
    if K < 2:
        raise input_error(
            where, f"a run with {K} complete revolution(s)", "at least 2 per run (noise)"
        )
    has_ref = tab.phi_ref_rad is not None
    phi = tab.phi_ref_rad if has_ref else tab.phi_meas_rad
    # (R, K, F, M) arrays; extra revolutions beyond the shortest run's are left out
    v = np.zeros((R, K, F, M))
    tf = np.zeros((R, K, F))
    tm = np.zeros((R, K, M))
    tmid = np.zeros((R, K))
    dropped = 0
    for r in range(R):
        s = np.flatnonzero(tab.run == r)
        n_rev = s.size // (F * M)
        dropped += n_rev - K
        s = s[: K * F * M].reshape(K, F, M)
        v[r] = _wrap(tab.value_rad[s] - phi[r])
        tf[r] = tab.t_fixed_s[s][:, :, 0]
        tm[r] = tab.t_moving_s[s][:, 0, :]
        tmid[r] = tab.t_mid_s[s][:, 0, 0]
    if not has_ref:
        # the run's mean reading is the reference: residual values are small and centred
        v = _wrap(v - _wrap(np.mean(v, axis=(1, 2, 3), keepdims=True)))
    H = _helmert(K)
    y = np.einsum("kr,nrm->nkm", H, v.mean(axis=2))
    if not has_ref:
        y[:, 0, :] -= y[:, 0, :].mean(axis=1, keepdims=True)
    y = y.reshape(R, K * M)
    names = [f"m{m}" if k == 0 else f"m{m}.d{k}" for k in range(K) for m in range(M)]
    t_run = tmid.mean(axis=1)
    t_mean = float(tmid.mean())
    omega = 2 * np.pi / tab.period_s
    enc = rec.encoder
    clock_hz = enc.get("clock_hz")
    lattice = stamp_lattice(np.asarray(rec.columns["t"], float), settings=settings)
    clock_s = 1.0 / float(clock_hz) if clock_hz else None
    lock = clock_lock_share(tab.run_clock_s, clock_s, K, tab.n_marks)
    rows_extra = dict(
        phi=np.asarray(phi, float),
        tf_c=tf - t_mean,
        tm_c=tm - t_mean,
        tmid_c=tmid - t_mean,
        run_index=np.arange(R, dtype=float),
        # each fixed sensor's run mean (over revolutions and moving sensors), centred: its
        # differences between fixed sensors are the fixed sensors' run-to-run noise
        fixed_c=v.mean(axis=(1, 3)) - v.mean(axis=(0, 1, 3)),
    )
    constants = dict(
        psi_f=np.asarray(tab.psi_fixed_rad, float),
        psi_m=np.asarray(tab.psi_moving_rad, float),
        helmert=H,
        proj=np.asarray(0.0 if has_ref else 1.0),
        clock_lock=np.asarray(lock),
        # the clock's rounding constant within a run, common to the moving sensors (rad^2)
        clock_round_excess=np.asarray(
            rounding_common_excess(
                tab.run_clock_s, clock_s, tab.psi_fixed_rad, tab.psi_moving_rad, tab.n_marks, lock
            )
        ),
        omega=np.asarray(omega),
        t_mean=np.asarray(t_mean),
    )
    radius = enc.get("optical_radius_m")
    pp = int(enc.get("pole_pairs", 0) or 0)
    speed = (
        sds_speed_harmonics(rec, phi_rad=np.asarray(phi, float), max_order=max(pp - 1, 1))
        if pp > 1
        else None
    )
    return SDSKindData(
        y=y,
        shaft=np.asarray(phi, float),
        t=t_run,
        run=np.asarray(tab.run_ids),
        reading=np.zeros_like(y),
        theta_ref=np.asarray(phi, float) if has_ref else None,
        temp=None,
        alpha=np.zeros(K * M),
        radius_m=float(radius) if radius else None,
        signal_periods=0,
        project=False,
        unit="rad",
        channel_names=names,
        sensor="sds",
        where=where,
        table=tab,
        n_revs=K,
        lattice=lattice,
        declared_clock_s=1.0 / float(clock_hz) if clock_hz else None,
        rows_extra=rows_extra,
        constants=constants,
        dropped_revs=int(dropped),
        speed=speed,
    )


def _folds_by_run(R: int, k: int, seed: int = 0) -> tuple[np.ndarray, dict]:
    """Whole runs (platform positions) dealt at random into ``k`` balanced folds."""
    rng = np.random.default_rng(seed)
    fold = np.empty(R, dtype=int)
    fold[rng.permutation(R)] = np.arange(R) % k
    design = {
        "k": int(k),
        "scheme": "whole runs (platform positions) dealt at random into balanced folds "
        f"(seed {seed}); a fold's runs are predicted from the model fitted on the others",
        "block": "run",
        "seed": seed,
        "folds": [[int(r) for r in np.flatnonzero(fold == f)] for f in range(k)],
    }
    return fold, design


def sds_prepare(
    kd: SDSKindData, meta: dict, settings: FinderSettings = DEFAULT_SETTINGS
) -> Prepared:
    """Stage 1 for sds: one row per run, every run kept (an SDS run is a platform at rest:
    there is no shaft motion to segment), folds of whole runs, first noise levels."""
    from ...engine._protocol import Prepared

    R, C = kd.y.shape
    if not np.all(np.isfinite(kd.y)):
        raise input_error(kd.where, "non-finite SDS readings", "finite edge times")
    k = int(min(settings.n_folds, R))
    if k < 4:
        raise input_error(kd.where, f"{R} runs", "at least 4 runs for the held-out folds")
    fold, design = _folds_by_run(R, k)
    t = np.asarray(kd.t, float)
    # one row per run: the engine's row columns, its run one-hot made on access (identity)
    rows = RowColumns(
        dict(
            t=t,
            tau=t - t[0],
            theta=kd.shaft,
            theta_ref=kd.theta_ref if kd.theta_ref is not None else np.zeros(R),
            reading=kd.reading,
            omega=np.zeros(R),
            direction=np.ones(R),
            driver=t - t.mean(),
            psi=np.zeros_like(kd.y),
            **kd.rows_extra,
        ),
        np.arange(R),
        R,
    )
    consts = dict(
        step_width_s=np.asarray(1e-3),
        alpha=np.asarray(kd.alpha, float),
        radius_m=np.asarray(kd.radius_m or REFERENCE_RADIUS_M, float),
        signal_periods=np.asarray(0.0),
        n_runs=np.asarray(float(R)),
        **kd.constants,
    )
    enc = meta.get("encoder", {})
    pp = int(enc.get("pole_pairs", 0) or 0)
    lim = max(1, R * kd.constants["psi_m"].size // 2 - 1)
    orders = (
        design_orders(pp, enc.get("stator_coils"), enc.get("commutation_states"), lim)
        if pp > 0
        else []
    )
    sigma = run_mean_levels(kd.n_revs, rows, consts, orders, settings)(kd.y)
    ctx = Context(
        kind="sds",
        n_channels=C,
        n_runs=R,
        has_ref=kd.theta_ref is not None,
        sensor="sds",
        signal_periods=0,
        radius_m=kd.radius_m,
        rows=rows,
        consts=consts,
        noise=sigma.copy(),
        revolutions=np.full(R, float(kd.n_revs)),
        meta=meta,
        settings=settings,
        driver_name="time",
        data=kd,
    )
    return Prepared(
        kd=kd,
        ctx=ctx,
        y=kd.y.copy(),
        rows=rows,
        consts=consts,
        keep=np.ones(R, bool),
        fold=fold,
        seg=np.arange(R),
        sigma=sigma,
        excluded=[],
        glitches=[],
        count_jumps=[],
        gaps=[],
        fold_design=design,
        run_ids=np.asarray(sorted(set(kd.run.tolist()), key=kd.run.tolist().index)),
        run=np.arange(R),
        settings=settings,
    )
