"""``sds`` kind of the discrepancy-finder engine (edge times of a shifted-delta-sum bench).

Data (:func:`sds_pair_table`): every run (one platform position φ_r) and every complete
revolution gives one shifted delta sum per fixed × moving sensor pair (seed 001 eqs. 23–24,
pair constants from the nominal sensor azimuths of the TOML), with the mean time of each
sensor's window. The engine sees **one row per run** and, per moving sensor ``m``, ``K``
channels: the run mean over the ``K`` revolutions (channel ``m<i>``, the pair values averaged
over the fixed sensors, minus ``φ_ref``) and ``K − 1`` orthonormal (Helmert) contrasts over the
revolutions (channels ``m<i>.d<k>``), so that the two noise levels of an SDS bench (run to
run, e.g. clock ticks locked to the revolution, and revolution to revolution) are separate
channels with their own noise, and rows (runs) are independent. Every term is computed per
pair and revolution and mapped the same way, so it stays one differentiable function.

Base model (what the design includes), per pair (f, m), with ``x = φ_r + ψ_m``:

    y = c_m + Σ_{n ∈ design orders} a_n cos n x + b_n sin n x

the pair constants averaged over the fixed sensors ``c_m`` and the product of the design's
speed ripple with disk B's mark errors at the design motor's orders (multiples of
``pole_pairs``, of ``pole_pairs·commutation_states`` and the cogging order, up to
``R·M/2 − 1``; seed 001 eqs. 46–53). Without ``phi_ref`` the datum is ``wrap(SDS − φ̂_r)``
with φ̂_r the run's mean reading, and every term is projected on the differences between the
moving sensors of a run (the per-run offset is a nuisance that takes everything common to
the moving sensors): the absolute angle per run, the common constant, what is common to the
moving sensors (beam tilt × axial runout, coil orders at multiples of M, a common drift
across runs) are unidentifiable and listed.

Candidates (``docs/effects.md``, "SDS timing model"), each a differentiable term:

* ``axis_tilt``: ``T(φ+ψ_m) − T(ψ_f)``, ``T(ψ) = atan2(sin(ψ−χ), cos(ψ−χ) cos β) − (ψ−χ)``
  (seed eq. 26), parameters β (rad), χ (rad); χ is unidentifiable when β is not resolved;
* ``thermal_drift``: ``k (t_m − t̄)`` (no temperature column in sds: time drives);
* ``bearing_wobble``: ``w(t_m, φ+ψ_m) − w(t_f, ψ_f)``,
  ``w = sinc(ρ) [A sin(ρΩt − ψ) + B cos(ρΩt − ψ)]`` (window mean over one revolution);
* ``beam_tilt_axial``: ``Σ_{n=1..3} p_n cos nφ + q_n sin nφ`` common to the moving sensors;
* ``coil_mismatch``: Fourier terms in ``x`` at the coil orders ``1 … pole_pairs − 1``;
* ``sensor_delay_step``: one moving sensor's edges delayed by ``τ_m`` from one run on
  (electronics, cable, a re-plugged connector): ``+Ω τ_m`` on that sensor's pairs;
* ``timing_quantization``: the time stamps lie on a lattice coarser than the declared clock
  (:func:`stamp_lattice`, found from the data for any clock); a noise floor, named from the
  lattice, not fitted.

Views: the engine's ``orders`` (per channel, in φ), a run-step view (per moving sensor, the
best change point over the runs in time order, and single-run outliers) and one matched
view per candidate (the power its columns take out of the whitened residual).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from .._errors import input_error
from ..io._recording import Recording
from ._candidates import Candidate, Context, Param
from ._engine import Kind, KindData, Prepared, RowColumns, _valjac_fn
from ._views import Finding, _logp, _thr, _where

__all__ = [
    "SDS",
    "SDSPairTable",
    "sds_pair_table",
    "sds_speed_harmonics",
    "stamp_lattice",
]

REFERENCE_RADIUS_M = 0.0254
BEAM_ORDERS = (1, 2, 3)
N_FOLDS = 5
LATTICE_COARSER = 1.05
"""A stamp lattice this much coarser than the declared clock is reported."""

EXPLANATIONS = {
    "axis_tilt": (
        "The disk axis is tilted against the platform axis; the sensors then read the disk at "
        "projected azimuths (seed 001 eq. 26), an error of nearly pure order 2 in the "
        "platform angle, about tilt²/4. The simulation assumed both axes aligned."
    ),
    "thermal_drift": (
        "The moving sensors drift against their disk with temperature (seed 001: about "
        "0.7 arcsec/K); with no temperature column the drift shows as a trend in time. The "
        "simulation held the temperature constant."
    ),
    "bearing_wobble": (
        "The shaft bearings move the disk centre at a frequency that is not a multiple of the "
        "shaft speed (cage, balls); the error changes from one revolution to the next and "
        "cancels only in opposed sensor pairs. The simulation assumed perfect bearings."
    ),
    "beam_tilt_axial": (
        "The moving sensors' beams are tilted tangentially and the platform moves axially as "
        "it turns (axial runout), so the read point slides along the track: an error in the "
        "platform angle common to all moving sensors. Only the product tilt × runout is seen."
    ),
    "coil_mismatch": (
        "Unequal stator coils make the shaft speed ripple at orders below the pole-pair count; "
        "with the disk's mark errors at the same orders it biases the shifted delta sum "
        "(seed 001 eqs. 46-53). The design's motor had no such ripple."
    ),
    "sensor_delay_step": (
        "One moving sensor's edges arrive later (or earlier) from one run on: a delay in its "
        "electronics or cable changed (a re-plugged connector, a thermal step in a "
        "comparator). Its pairs read +Omega*tau from then on. The design has fixed delays."
    ),
    "timing_quantization": (
        "The edges are stamped on a coarser clock than the declared one, which adds a noise "
        "floor to every reading (it cannot be fitted away, only made smaller with a faster "
        "clock)."
    ),
}


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


def _wrap(x):
    return np.mod(np.asarray(x) + np.pi, 2 * np.pi) - np.pi


def _split_runs(rec: Recording):
    from ..io._sds_format import check_sds_columns
    from ..io._sds_format import sensor_counts as _sensor_counts

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
    refs, meas, periods = [], [], []
    for i, (r, times, marks, ref) in enumerate(runs):
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


def stamp_lattice(t: np.ndarray, max_samples: int = 200_000) -> dict[str, Any]:
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
        on = np.abs(q - n) < 0.02
        frac = float(np.mean(on))
        if frac >= 0.995:
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
    """:class:`~encdesign.diagnose._engine.KindData` plus the SDS pair table and clock."""

    table: Any = None
    n_revs: int = 0
    lattice: dict | None = None
    declared_clock_s: float | None = None
    rows_extra: dict | None = None
    consts_extra: dict | None = None
    dropped_revs: int = 0
    speed: dict | None = None


def _design_orders(p: int, q: int | None, c: int | None, cap: int) -> list[int]:
    orders = set(range(p, cap + 1, p))
    if c:
        orders |= set(range(p * c, cap + 1, p * c))
    if q:
        cog = 2 * p * q // math.gcd(2 * p, q)
        orders |= set(range(cog, cap + 1, cog))
    return sorted(o for o in orders if o <= cap)


def sds_data(rec: Recording) -> SDSKindData:
    """Rows (runs) and channels (moving sensor × {run mean, revolution contrasts})."""
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
    lattice = stamp_lattice(np.asarray(rec.columns["t"], float))
    rows_extra = dict(
        phi=np.asarray(phi, float),
        tf_c=tf - t_mean,
        tm_c=tm - t_mean,
        tmid_c=tmid - t_mean,
        run_index=np.arange(R, dtype=float),
    )
    consts_extra = dict(
        psi_f=np.asarray(tab.psi_fixed_rad, float),
        psi_m=np.asarray(tab.psi_moving_rad, float),
        helmert=H,
        proj=np.asarray(0.0 if has_ref else 1.0),
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
        consts_extra=consts_extra,
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


def sds_prepare(kd: SDSKindData, meta: dict) -> Prepared:
    """Stage 1 for sds: one row per run, every run kept (an SDS run is a platform at rest:
    there is no shaft motion to segment), folds of whole runs, first noise levels."""
    from ._engine import Prepared

    R, C = kd.y.shape
    if not np.all(np.isfinite(kd.y)):
        raise input_error(kd.where, "non-finite SDS readings", "finite edge times")
    k = int(min(N_FOLDS, R))
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
        **kd.consts_extra,
    )
    enc = meta.get("encoder", {})
    pp = int(enc.get("pole_pairs", 0) or 0)
    lim = max(1, R * kd.consts_extra["psi_m"].size // 2 - 1)
    orders = (
        _design_orders(pp, enc.get("stator_coils"), enc.get("commutation_states"), lim)
        if pp > 0
        else []
    )
    consts["base_orders"] = orders
    X, _ = _saturating_columns(rows, consts, orders)
    sigma = _level_sigma(kd.y, kd.n_revs, X, float(consts["proj"]) > 0)
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
    )
    ctx.consts["driver_name"] = "time"  # type: ignore[index]
    ctx.consts["kd"] = kd  # type: ignore[index]
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
    )


SATURATE_FRACTION = 0.6
"""The saturated noise fit of the run means uses at most this fraction of their values."""


def _saturating_columns(rows: dict, consts: dict, orders_base: list[int]) -> tuple:
    """Columns ``(R*M, q)`` over the run-mean channels that span every smooth structure a
    platform bench can put there: a constant per moving sensor, rotating orders ``1..L``
    and the design orders in ``x = φ + ψ_m``, common orders ``1..L`` in ``φ``, a drift in
    time; ``L`` as large as ``SATURATE_FRACTION`` of the values allows. Projected on the
    moving-sensor differences without ``phi_ref``."""
    phi = np.asarray(rows["phi"], float)
    psi_m = np.asarray(consts["psi_m"], float)
    R, M = phi.size, psi_m.size
    x = phi[:, None] + psi_m[None, :]
    ph = np.broadcast_to(phi[:, None], (R, M))
    t = np.broadcast_to(np.asarray(rows["tmid_c"]).mean(1)[:, None], (R, M))
    cols = [np.eye(M)[None, :, :].repeat(R, 0).reshape(R * M, M)]
    n0 = M + 1 + 2 * len(orders_base)
    L = int(max(0, (SATURATE_FRACTION * R * M - n0) // 4))
    L = min(L, max(1, (R - 1) // 2))
    rot = sorted(set(range(1, L + 1)) | set(orders_base))
    for n in rot:
        cols += [np.cos(n * x).reshape(-1, 1), np.sin(n * x).reshape(-1, 1)]
    for n in range(1, L + 1):
        cols += [np.cos(n * ph).reshape(-1, 1), np.sin(n * ph).reshape(-1, 1)]
    cols.append((t / max(np.ptp(t), 1e-12)).reshape(-1, 1))
    X = np.concatenate(cols, 1)
    if float(consts["proj"]) > 0:
        X3 = X.reshape(R, M, -1)
        X = (X3 - X3.mean(1, keepdims=True)).reshape(R * M, -1)
    return X, L


SIGMA_TEST_P = 1e-4
"""Tail probability at which the run-mean noise level is widened for its estimation error
(:func:`dof_widening`)."""


def dof_widening(nu: float, q: int = 2, p: float = SIGMA_TEST_P) -> float:
    """Factor ``c`` on a noise level estimated with ``nu`` degrees of freedom so that the
    engine's tests, which treat the level as known (chi-square thresholds), keep their
    false-alarm rate: ``c² = q F⁻¹(1 − p; q, nu) / χ²⁻¹(1 − p; q)``, the ratio of the
    F-test's threshold to the chi-square test's for a ``q``-parameter term at tail
    probability ``p`` (about the engine's Bonferroni-corrected levels; for ``nu`` = 18, c is
    1.3 for q = 1…6 within 0.05). 1 for ``nu`` → ∞."""
    if not np.isfinite(nu) or nu > 1e4:
        return 1.0
    nu = max(float(nu), 1.0)
    return float(math.sqrt(q * stats.f.isf(p, q, nu) / stats.chi2.isf(p, q)))


def _sensor_helmert(M: int) -> np.ndarray:
    """Orthonormal ``(M, M)`` basis over the moving sensors: column 0 common (1/√M each),
    columns 1… the differences."""
    H = np.zeros((M, M))
    H[:, 0] = 1.0 / math.sqrt(M)
    for k in range(1, M):
        H[:k, k] = 1.0
        H[k, k] = -k
        H[:, k] /= math.sqrt(k * (k + 1))
    return H


def _level_sigma(
    resid: np.ndarray, K: int, X: np.ndarray, proj: bool = False, info: dict | None = None
) -> np.ndarray:
    """Noise per channel: one level for the run means, one for the revolution contrasts
    (each pooled over the moving sensors, which see the same clock and marks).

    Run means: the residual of a saturated least-squares fit (:func:`_saturating_columns`:
    every smooth pattern in the platform angle up to order ``L``, so no catalog effect and
    no low order can inflate it), plus the significant change points (a step on one sensor
    from one run on) and single-value outliers (one sensor in one run), each searched for
    and tested as F(1, dof) against what is left (Bonferroni), so neither can inflate it
    either. The level is ``sqrt(SSR / nu)`` with ``nu`` = independent values − rank (without
    ``phi_ref`` the values of a run are projected on the moving-sensor differences: ``R·(M −
    1)`` independent values, not ``R·M``), then widened by :func:`dof_widening` (``nu``) for
    its estimation error: with ~12 platform positions it is known to ~±17 %, which the
    engine's known-level tests would otherwise turn into false alarms.

    Contrasts: the robust scale (1.4826 MAD) of the contrasts themselves (nothing constant
    within a run reaches them), separately for the part common to the moving sensors (the
    fixed sensors' timing noise enters every pair alike) and for the differences; the larger
    per-value level is used (the engine weighs channels as independent: this keeps its tests
    conservative for common and differential patterns alike)."""
    R, C = resid.shape
    M = C // K
    out = np.empty(C)
    ym = resid[:, :M].ravel()
    n_ind = R * (M - 1) if proj else R * M

    def basis(X):
        Q, Rm = np.linalg.qr(X)
        d = np.abs(np.diag(Rm))
        return Q[:, d > 1e-10 * max(float(d.max(initial=0.0)), 1e-300)]

    # candidate columns: a change point per sensor and run, a single value per sensor and run
    cols = []
    for m in range(M):
        for k in range(1, R):
            a = np.zeros((R, M))
            a[k:, m] = 1.0
            cols.append(a)
        for r in range(R):
            a = np.zeros((R, M))
            a[r, m] = 1.0
            cols.append(a)
    A = np.stack(cols, -1)  # (R, M, n_cols)
    if proj:
        A = A - A.mean(1, keepdims=True)
    A = A.reshape(R * M, -1)
    n_tests = max(1, A.shape[1])
    Q = basis(X)
    added = 0
    for _ in range(2 * M):
        e = ym - Q @ (Q.T @ ym)
        ssr0 = float(e @ e)
        dof = n_ind - Q.shape[1] - 1
        if dof < 3 or ssr0 <= 0:
            break
        Ap = A - Q @ (Q.T @ A)
        nn = np.sum(Ap**2, 0)
        ok = nn > 1e-10 * np.sum(A**2, 0)
        gain = np.where(ok, (e @ Ap) ** 2 / np.where(ok, nn, 1.0), 0.0)
        j = int(np.argmax(gain))
        f = gain[j] / ((ssr0 - gain[j]) / dof) if ssr0 > gain[j] else np.inf
        if not ok[j] or f <= stats.f.isf(1e-3 / n_tests, 1, dof):
            break
        Q = basis(np.concatenate([Q, Ap[:, j : j + 1]], 1))
        added += 1
    e = ym - Q @ (Q.T @ ym)
    ssr0, rk0 = float(e @ e), Q.shape[1]
    nu = max(n_ind - rk0, 1)
    s_raw = math.sqrt(ssr0 / nu) if ssr0 > 0 else 0.0
    c = dof_widening(nu)
    out[:M] = s_raw * c
    if C > M:
        H = _sensor_helmert(M)
        z = resid[:, M:].reshape(R, K - 1, M) @ H
        parts = [z[..., :1].ravel()] + ([z[..., 1:].ravel()] if M > 1 else [])
        lv = []
        for x in parts:
            s = 1.4826 * float(np.median(np.abs(x)))
            lv.append(s if s > 0 else float(np.sqrt(np.mean(x**2))))
        out[M:] = max(lv)
    if info is not None:
        info.update(
            run_means_rad=s_raw,
            run_means_dof=int(nu),
            run_means_widening=c,
            run_means_steps_or_outliers=added,
            contrasts_common_rad=lv[0] if C > M else None,
            contrasts_differences_rad=lv[1] if C > M and M > 1 else None,
        )
    if not np.all(np.isfinite(out)) or np.any(out <= 0):
        out = np.full(C, float(np.std(resid)) or 1e-12)
    return out


def sds_noise(prep: Prepared, resid: np.ndarray) -> np.ndarray:
    """Noise hook: the two levels of :func:`_level_sigma` on the base residual. Also keeps
    the base residual's common-order powers (:func:`common_order_power`) for the
    plausibility of ``beam_tilt_axial``."""
    X, _ = _saturating_columns(prep.rows, prep.consts, prep.consts.get("base_orders", []))
    info: dict = {}
    sig = _level_sigma(
        resid[prep.keep], prep.kd.n_revs, X, float(prep.consts["proj"]) > 0, info=info
    )
    prep.ctx.consts["noise_info"] = info  # type: ignore[index]
    M = prep.consts["psi_m"].size
    rwm = resid[:, :M] / sig[None, :M]
    # a tuple, not an array: arrays in consts are passed to every term
    pw = common_order_power(prep, rwm)
    prep.ctx.consts["common_order_power"] = tuple(float(v) for v in pw)  # type: ignore[index]
    prep.ctx.consts["drift_vs_orders"] = _drift_vs_orders(prep, rwm, pw)  # type: ignore[index]
    prep.ctx.consts["run_change_power"] = tuple(  # type: ignore[index]
        _step_or_outlier(rwm[:, m]) for m in range(M)
    )
    return sig


def _step_or_outlier(x: np.ndarray) -> tuple[float, int, float, int, float]:
    """``(power, first run index)`` of the best step over the runs and of the best
    single-run outlier in one sensor's whitened run means (each 1 dof, less the mean), and
    the sensor's total power."""
    R = x.size
    x = x - x.mean()
    best_s, k_s = 0.0, 1
    for k in range(1, R):
        s = (np.arange(R) >= k).astype(float)
        s -= s.mean()
        pw = float((s @ x) ** 2 / (s @ s))
        if pw > best_s:
            best_s, k_s = pw, k
    j = int(np.argmax(np.abs(x)))
    return best_s, k_s, float(x[j] ** 2 * R / max(R - 1, 1)), j, float(x @ x)


def _drift_vs_orders(prep: Prepared, rwm: np.ndarray, pw: np.ndarray) -> dict | None:
    """A drift in time against the orders of the platform angle, both common to the moving
    sensors, on the whitened base run means: the drift's power (1 dof), the best order's
    (2 dof) and the correlation of the drift column with that order's two columns. With the
    platform stepped by a fixed angle (e.g. golden-angle steps), order ``n`` advances by a
    nearly fixed phase per run: over a few runs it is nearly a trend in time (order 5 with
    golden steps), so the two can be confounded."""
    if float(prep.consts["proj"]) > 0 or pw.size == 0:
        return None
    R, M = rwm.shape
    phi = np.asarray(prep.rows["phi"], float)
    t = np.asarray(prep.rows["tmid_c"], float).mean(1)
    y = (rwm - rwm.mean(0, keepdims=True)).ravel()
    d = np.repeat(t - t.mean(), M)
    pd = float((d @ y) ** 2 / max(d @ d, 1e-300))
    n = int(np.argmax(pw)) + 1
    X = np.stack(
        [np.cos(n * phi) - np.cos(n * phi).mean(), np.sin(n * phi) - np.sin(n * phi).mean()], 1
    )
    X = np.repeat(X, M, axis=0)
    Q, _ = np.linalg.qr(X)
    dn = d / max(np.linalg.norm(d), 1e-300)
    rho = float(np.linalg.norm(Q.T @ dn))
    return {
        "drift_power": pd,
        "order": n,
        "order_power": float(pw[n - 1]),
        "correlation": rho,
        "n_values": int(R * M),
    }


def _common_max_order(R: int) -> int:
    return int(max(1, (R - 1) // 2))


def common_order_power(prep: Prepared, rwm: np.ndarray) -> np.ndarray:
    """Chi-square (2 dof) of orders ``1..(R-1)//2`` in the platform angle φ, one coefficient
    pair for all moving sensors (a pattern common to them), in the whitened run means
    ``rwm`` (R, M), less a constant per sensor."""
    phi = np.asarray(prep.rows["phi"], float)
    R, M = rwm.shape
    y = (rwm - rwm.mean(0, keepdims=True)).ravel()
    out = []
    for n in range(1, _common_max_order(R) + 1):
        c = np.repeat(np.cos(n * phi), M).reshape(R, M)
        sn = np.repeat(np.sin(n * phi), M).reshape(R, M)
        X = np.stack([(c - c.mean(0)).ravel(), (sn - sn.mean(0)).ravel()], 1)
        if float(prep.consts["proj"]) > 0:
            X = np.zeros_like(X)  # common to the moving sensors: taken by the run offsets
        out.append(_ls_power_flat(y[:, None], X[:, None, :]))
    return np.asarray(out)


def view_common_orders(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """Orders in φ common to every moving sensor (platform gear, axial runout, a reference
    error), 2 dof each, Bonferroni over the orders; nothing without ``phi_ref``."""
    M = prep.consts["psi_m"].size
    if float(prep.consts["proj"]) > 0:
        return []
    pw = common_order_power(prep, rw[:, :M])
    thr = _thr(2, pw.size)
    out = []
    for i in np.flatnonzero(pw > thr):
        out.append(
            Finding(
                "common_orders",
                _where(orders=[float(i + 1)], heads=list(range(M)), runs=prep.run_ids.tolist()),
                float(pw[i]),
                2,
                _logp(float(pw[i]), 2),
                detail={"n_values": int(rw.shape[0] * M), "common_to_moving_sensors": True},
            )
        )
    return out


def _coil_plausible(ctx: Context, params: dict) -> str | None:
    """Coil orders that are multiples of the moving-sensor count are a pattern common to
    the moving sensors: refused when that is the fitted effect's main part and the base
    residual's common structure peaks at another order (aliased through the platform
    positions)."""
    M = int(ctx.consts["psi_m"].size)
    amp = np.hypot(np.asarray(params["cos_rad"]), np.asarray(params["sin_rad"]))
    n = int(np.argmax(amp)) + 1
    pw = np.asarray(ctx.consts.get("common_order_power", ()), float)
    if M < 2 or n % M or pw.size == 0:
        return None
    top = int(np.argmax(pw)) + 1
    own = pw[min(n, pw.size) - 1]
    if top != n and pw[top - 1] > 2 * own:
        return (
            f"its main order {n} is common to the moving sensors, but the common structure "
            f"peaks at order {top} of the platform angle (chi-square {pw[top - 1]:.0f})"
        )
    return None


def _transient(ctx: Context) -> str | None:
    """A one-run transient on one sensor dominates the base residual: that sensor's
    largest single-run deviation is significant (1 dof, Bonferroni over sensors × runs),
    fits better than any step and holds over half of the sensor's power. A smooth
    effect fitted to such a record would take a part of the transient; it is not named."""
    ch = ctx.consts.get("run_change_power")
    if not ch:
        return None
    R = int(ctx.n_runs)
    thr = _thr(1, 2 * len(ch) * max(R - 1, 1))
    for m, (ps, _, po, jo, tot) in enumerate(ch):
        if po > thr and po > ps and po > 0.5 * tot:
            return (
                f"the base residual is dominated by one run's deviation on m{m} (run index "
                f"{jo}, chi-square {po:.0f} of the sensor's {tot:.0f}): a transient no "
                "catalog effect makes, reported as unexplained"
            )
    return None


def _no_transient(fn=None):
    def plausible(ctx: Context, params: dict) -> str | None:
        return _transient(ctx) or (fn(ctx, params) if fn is not None else None)

    plausible.__doc__ = (fn.__doc__ or "") + " Refused, too, when :func:`_transient` says so."
    return plausible


def _drift_plausible(ctx: Context, params: dict) -> str | None:
    """A drift in time is refused when an order of the platform angle (common to the
    moving sensors) fits the base residual's common structure better by more than one
    parameter's worth (BIC: ln of the number of run means): with the platform stepped by a
    fixed angle such an order is nearly a trend over the runs, and the better fit is the
    order (out of catalog: reported, not named)."""
    dv = ctx.consts.get("drift_vs_orders")
    if not dv:
        return None
    if dv["order_power"] - dv["drift_power"] > math.log(max(dv["n_values"], 2)):
        return (
            f"order {dv['order']} of the platform angle fits the common structure better "
            f"(chi-square {dv['order_power']:.0f}, 2 dof, vs {dv['drift_power']:.0f}, 1 dof) "
            f"and is nearly a trend over these runs (correlation {dv['correlation']:.2f} with "
            "a drift): not a drift in time"
        )
    return None


def _delay_gauge(ctx: Context, delay) -> np.ndarray:
    """The fitted delays per moving sensor; without phi_ref a delay common to every moving
    sensor is taken by the per-run offset, so the delays are known up to a common value:
    the median is taken out (one sensor's step then shows on that sensor alone)."""
    d = np.asarray(delay, float)
    if float(np.asarray(ctx.consts["proj"])) > 0 and d.size > 2:
        d = d - np.median(d)
    return d


def _delay_plausible(ctx: Context, params: dict) -> str | None:
    """A delay step is one sensor's (its electronics, its cable): refused when another
    moving sensor carries more than half of the largest step (a pattern common to the
    moving sensors, e.g. a drift or a platform-angle order, is not a sensor's delay)."""
    dd = np.abs(_delay_gauge(ctx, params["delay_s"]))
    d = np.sort(dd)[::-1]
    if d.size > 1 and d[1] > 0.5 * d[0]:
        return (
            f"the step is shared by several moving sensors ({d[1] / d[0]:.0%} of the largest "
            "on the next one): not one sensor's delay"
        )
    # a delay change persists: a change confined to one run (a single-run outlier fits the
    # sensor's base run means better than any step, both 1 dof) is a transient, not a step
    ch = ctx.consts.get("run_change_power")
    if ch:
        m = int(np.argmax(dd))
        ps, ks, po, jo, _ = ch[m]
        if po > ps * (1 + 1e-9):
            return (
                f"the change on m{m} is confined to one run (run index {jo}: a single-run "
                f"outlier fits with chi-square {po:.0f}, the best step from one run on with "
                f"{ps:.0f}): a transient in one run, not a persisting delay step"
            )
    return None


def _beam_plausible(ctx: Context, params: dict) -> str | None:
    """Beam tilt x axial runout lives at orders 1..3 of φ: refused when the base residual's
    strongest common order is another one (an out-of-catalog order that orders 1..3 take in
    part through the sparse platform positions)."""
    pw = np.asarray(ctx.consts.get("common_order_power", ()), float)
    if pw.size == 0:
        return None
    top = int(np.argmax(pw)) + 1
    if top not in BEAM_ORDERS and pw[top - 1] > 2 * max(
        pw[n - 1] for n in BEAM_ORDERS if n <= pw.size
    ):
        return (
            f"the common structure peaks at order {top} of the platform angle (chi-square "
            f"{pw[top - 1]:.0f}), not at the beam-tilt orders {list(BEAM_ORDERS)}"
        )
    return None


# ----------------------------------------------------------------------------- terms


def _to_channels(vp, x):
    """Pair values ``(n, K, F, M)`` -> channels ``(n, K*M)``: mean over the fixed sensors,
    Helmert over the revolutions, projection on the moving-sensor differences without
    ``phi_ref``."""
    v = jnp.mean(vp, axis=2)  # (n, K, M)
    out = jnp.einsum("kr,nrm->nkm", x["helmert"], v)
    m0 = out[:, :1, :]
    m0 = m0 - x["proj"] * jnp.mean(m0, axis=2, keepdims=True)
    out = jnp.concatenate([m0, out[:, 1:, :]], axis=1)
    return out.reshape(out.shape[0], -1)


def _xk(x):
    """``x = φ_r + ψ_m`` broadcast to ``(n, K, F, M)``; ψ_f likewise; shape helpers."""
    n, K, F = x["tf_c"].shape
    M = x["psi_m"].shape[0]
    xm = (x["phi"][:, None] + x["psi_m"][None, :])[:, None, None, :]
    xm = jnp.broadcast_to(xm, (n, K, F, M))
    pf = jnp.broadcast_to(x["psi_f"][None, None, :, None], (n, K, F, M))
    return xm, pf, (n, K, F, M)


def _fourier_terms(orders, a, b, ang):
    o = jnp.asarray(orders, dtype=float)
    arg = ang[..., None] * o
    return jnp.sum(jnp.cos(arg) * a + jnp.sin(arg) * b, axis=-1)


def _tilt(psi, beta, chi):
    a = psi - chi
    d = jnp.arctan2(jnp.sin(a), jnp.cos(a) * jnp.cos(beta)) - a
    return jnp.mod(d + jnp.pi, 2 * jnp.pi) - jnp.pi


@functools.lru_cache(maxsize=32)
def _const_term(M: int) -> Candidate:
    def fn(p, x):
        xm, _, shp = _xk(x)
        vp = jnp.broadcast_to(p["const_rad"][None, None, None, :], shp)
        return _to_channels(vp, x)

    return Candidate(
        "pair_constants",
        fn,
        (Param("const_rad", "rad", (M,), description="pair constant per moving sensor"),),
        kinds=("sds",),
        explanation="base model: pair constants (azimuth errors, mean mark errors)",
    )


@functools.lru_cache(maxsize=32)
def _ripple_term(orders: tuple[int, ...], name: str = "design_ripple", expl: str = "") -> Candidate:
    k = len(orders)

    def fn(p, x):
        xm, _, _ = _xk(x)
        return _to_channels(_fourier_terms(orders, p["cos_rad"], p["sin_rad"], xm), x)

    return Candidate(
        name,
        fn,
        (Param("cos_rad", "rad", (k,)), Param("sin_rad", "rad", (k,))),
        signature=(f"sds_{name}",) if name != "design_ripple" else (),
        kinds=("sds",),
        explanation=expl
        or "base model: the design's speed ripple times disk B's mark errors (orders in x)",
        derived=_ripple_derived(orders),
    )


def _ripple_derived(orders):
    def derived(ctx, v, se):
        amp = np.hypot(v["cos_rad"], v["sin_rad"])
        sa = np.hypot(se["cos_rad"], se["sin_rad"]) / math.sqrt(2)
        out = {
            f"order_{o}_amplitude_rad": {
                "value": float(amp[i]),
                "se": float(sa[i]) if np.isfinite(sa[i]) else None,
                "unit": "rad",
            }
            for i, o in enumerate(orders)
        }
        kd = ctx.consts.get("kd")
        sp = getattr(kd, "speed", None)
        if sp is not None:
            # the shaft speed ripple itself, from the moving sensors' edge intervals
            for o in orders:
                if o in sp["orders"]:
                    j = int(np.flatnonzero(sp["orders"] == o)[0])
                    out[f"speed_ripple_relative_order_{o}"] = {
                        "value": float(sp["amplitude"][j]),
                        "se": float(sp["stderr"][j]),
                        "unit": "1",
                    }
        return out

    return derived


def _axis_tilt_fn(p, x):
    xm, pf, _ = _xk(x)
    beta, chi = p["tilt_rad"], p["azimuth_rad"]
    return _to_channels(_tilt(xm, beta, chi) - _tilt(pf, beta, chi), x)


def _drift_fn(p, x):
    xm, _, shp = _xk(x)
    tm = jnp.broadcast_to(x["tm_c"][:, :, None, :], shp)
    return _to_channels(p["drift_rate_rad_per_s"] * tm, x)


def _wobble_fn(p, x):
    xm, pf, shp = _xk(x)
    rho, a, b = p["frequency_ratio"], p["sin_rad"], p["cos_rad"]
    att = jnp.sinc(rho)
    t0 = x["t_mean"]
    tm = jnp.broadcast_to(x["tm_c"][:, :, None, :], shp) + t0
    tf = jnp.broadcast_to(x["tf_c"][:, :, :, None], shp) + t0

    def w(t, psi):
        arg = rho * x["omega"] * t - psi
        return att * (a * jnp.sin(arg) + b * jnp.cos(arg))

    # from run first_run on (held, no derivative): a bearing that began to wobble during
    # the record (0: every run)
    on = (x["run_index"] >= p.get("first_run", 0.0) - 0.5).astype(float)
    return _to_channels((w(tm, xm) - w(tf, pf)) * on[:, None, None, None], x)


def _wobble_onsets(R: int) -> list[int]:
    """Onsets tried for the bearing wobble: every run, or from a quarter, half or three
    quarters of the runs on (Bonferroni over them in its matched view)."""
    return sorted({0, *(int(round(R * f)) for f in (0.25, 0.5, 0.75))} - {R})


def _beam_fn(p, x):
    xm, _, shp = _xk(x)
    ph = jnp.broadcast_to(x["phi"][:, None, None, None], shp)
    return _to_channels(_fourier_terms(BEAM_ORDERS, p["cos_rad"], p["sin_rad"], ph), x)


def _delay_fn(p, x):
    xm, _, shp = _xk(x)
    on = (x["run_index"] >= p["first_run"] - 0.5).astype(float)  # held: no derivative
    # a later edge of the moving sensor reads a larger angle: +Omega tau
    d = x["omega"] * p["delay_s"][None, :] * on[:, None]  # (n, M)
    return _to_channels(jnp.broadcast_to(d[:, None, None, :], shp), x)


def _tilt_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    M = ctx.consts["psi_m"].size
    x = ctx.rows["phi"][:, None] + ctx.consts["psi_m"][None, :]
    r = resid[:, :M] / ctx.noise[None, :M]
    X = np.stack([np.cos(2 * x).ravel(), np.sin(2 * x).ravel(), np.ones(x.size)], 1)
    (a, b, _), *_ = np.linalg.lstsq(X, (r * ctx.noise[None, :M]).ravel(), rcond=None)
    amp = max(math.hypot(a, b), 1e-15)
    chi = math.atan2(-a, b) / 2
    beta = 2 * math.sqrt(amp)
    return [
        {"tilt_rad": np.asarray(beta), "azimuth_rad": np.asarray(c)} for c in (chi, chi + np.pi / 2)
    ]


def _wobble_grid(ctx: Context) -> np.ndarray:
    kd = ctx.consts["kd"]
    t = ctx.rows["tmid_c"]
    span_rev = max(float(np.ptp(t)) * float(ctx.consts["omega"]) / (2 * np.pi), 1.0)
    step = min(1 / (8 * span_rev), 0.01)
    del kd
    return np.arange(0.02, 0.98, step)


@jax.jit
def _wobble_cols_jit(rho, x):
    one, zero = jnp.ones(()), jnp.zeros(())
    a = _wobble_fn({"frequency_ratio": rho, "sin_rad": one, "cos_rad": zero}, x)
    b = _wobble_fn({"frequency_ratio": rho, "sin_rad": zero, "cos_rad": one}, x)
    return jnp.stack([a, b], -1)


_wobble_cols_grid = jax.jit(jax.vmap(_wobble_cols_jit, in_axes=(0, None)))


def _jx(ctx: Context) -> dict:
    x = {k: jnp.asarray(v) for k, v in ctx.rows.items()}
    x.update({k: jnp.asarray(v) for k, v in ctx.consts.items() if isinstance(v, np.ndarray)})
    return x


def _ls_power_flat(rw: np.ndarray, cols: np.ndarray) -> float:
    """Power (chi-square) the columns ``(n, C, q)`` take out of ``rw`` (n, C)."""
    X = cols.reshape(-1, cols.shape[-1])
    keep = np.any(np.abs(X) > 0, axis=0)
    X = X[:, keep]
    if X.shape[1] == 0:
        return 0.0
    Q, Rm = np.linalg.qr(X)
    ok = np.abs(np.diag(Rm)) > 1e-10 * np.abs(np.diag(Rm)).max()
    Q = Q[:, ok]
    return float(np.sum((Q.T @ rw.ravel()) ** 2))


def _wobble_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    rw = resid / ctx.noise[None, :]
    grid = _wobble_grid(ctx)
    allc = np.asarray(_wobble_cols_grid(jnp.asarray(grid), _jx(ctx)))  # (G, n, C, 2)
    run_index = np.asarray(ctx.rows["run_index"], float)
    onsets = _wobble_onsets(int(ctx.n_runs))
    # power of the two columns per (ratio, onset) from per-row normal equations summed over
    # the rows from the onset on (one pass, no QR per pair)
    c = allc / ctx.noise[None, None, :, None]
    a_row = np.einsum("gnci,gncj->gnij", c, c)
    g_row = np.einsum("gnci,nc->gni", c, rw)
    best = []
    for k in onsets:
        on = run_index >= k - 0.5
        A = a_row[:, on].sum(1)
        g = g_row[:, on].sum(1)
        A = A + 1e-12 * np.trace(A, axis1=1, axis2=2)[:, None, None] * np.eye(2)
        pw = np.einsum("gi,gi->g", g, np.linalg.solve(A, g[..., None])[..., 0])
        best += [(float(pw[i]), float(grid[i]), k) for i in range(grid.size)]
    best.sort(reverse=True)
    out, seen = [], []
    for _, rho, k in best:
        if all(abs(rho - s) > 0.03 for s in seen):
            seen.append(rho)
            out.append({"frequency_ratio": np.asarray(rho), "first_run": np.asarray(float(k))})
        if len(out) == 3:
            break
    if all(float(o["first_run"]) > 0 for o in out):
        # the stationary wobble at its best ratio stays among the starts
        _, rho, _ = max(b for b in best if b[2] == 0)
        out.append({"frequency_ratio": np.asarray(rho), "first_run": np.asarray(0.0)})
    return out


def _delay_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    firsts = []
    for f in findings:
        if f.view == "run_step" and f.detail.get("shape") == "step":
            firsts.append(int(f.detail["first_run_index"]))
    if not firsts:
        firsts = [_best_step(ctx, resid)[1]]
    out = []
    for k in dict.fromkeys(firsts):
        out.append({"first_run": np.asarray(float(k))})
    return out[:3]


def _best_step(ctx: Context, resid: np.ndarray) -> tuple[float, int, int]:
    """(power, first run index, moving sensor) of the strongest step over runs."""
    M = ctx.consts["psi_m"].size
    r = resid[:, :M] / ctx.noise[None, :M]
    R = r.shape[0]
    best = (0.0, R // 2, 0)
    for k in range(1, R):
        s = (np.arange(R) >= k).astype(float)
        s -= s.mean()
        pw = (s @ r) ** 2 / (s @ s)
        m = int(np.argmax(pw))
        if pw[m] > best[0]:
            best = (float(pw[m]), k, m)
    return best


def _no_ref_beam(ctx: Context) -> str | None:
    if ctx.has_ref:
        return None
    return (
        "without phi_ref the per-run offset takes everything common to the moving "
        "sensors; beam_tilt_axial (common to them) is unidentifiable"
    )


def _no_ref_drift(ctx: Context) -> str | None:
    if ctx.has_ref:
        return None
    return (
        "without phi_ref the per-run offset takes everything common to the moving sensors "
        "of a run; a drift in time moves them alike (their window times differ by less "
        "than a revolution: a constant per sensor), so thermal_drift is unidentifiable"
    )


def _tilt_derived(ctx, v, se):
    beta, sb = abs(float(v["tilt_rad"])), se["tilt_rad"]
    sb = float(sb) if np.isfinite(sb) else float("inf")
    out = {"tilt_squared_over_4_rad": {"value": beta**2 / 4, "se": None, "unit": "rad"}}
    if not beta > 3 * sb:
        out["azimuth_identifiable"] = {
            "value": False,
            "se": None,
            "unit": "1",
        }
    return out


def _wobble_derived(ctx, v, se):
    amp = math.hypot(float(v["sin_rad"]), float(v["cos_rad"]))
    s = math.hypot(float(se["sin_rad"]), float(se["cos_rad"])) / math.sqrt(2)
    s = s if math.isfinite(s) else None
    r = float(ctx.consts["radius_m"])
    k = int(round(float(v.get("first_run", 0.0))))
    rid = int(ctx.consts["kd"].table.run_ids[min(max(k, 0), int(ctx.n_runs) - 1)])
    return {
        "amplitude_rad": {"value": amp, "se": s, "unit": "rad"},
        "runout_m": {"value": amp * r, "se": None if s is None else s * r, "unit": "m"},
        "first_run": {"value": rid, "se": None, "unit": "1"},
    }


def _beam_derived(ctx, v, se):
    out = {}
    for i, n in enumerate(BEAM_ORDERS):
        a = math.hypot(float(v["cos_rad"][i]), float(v["sin_rad"][i]))
        s = math.hypot(float(se["cos_rad"][i]), float(se["sin_rad"][i])) / math.sqrt(2)
        out[f"order_{n}_amplitude_rad"] = {
            "value": a,
            "se": s if math.isfinite(s) else None,
            "unit": "rad",
        }
    return out


def _delay_derived(ctx, v, se):
    d = _delay_gauge(ctx, v["delay_s"])
    s = np.asarray(se["delay_s"], float)
    m = int(np.argmax(np.abs(d) / np.where(np.isfinite(s) & (s > 0), s, np.inf)))
    rid = int(ctx.consts["kd"].table.run_ids[int(v["first_run"])])
    return {
        "sensor": {"value": f"m{m}", "se": None, "unit": "1"},
        "first_run": {"value": rid, "se": None, "unit": "1"},
        "delay_step_s": {
            "value": float(d[m]),
            "se": float(s[m]) if np.isfinite(s[m]) else None,
            "unit": "s",
        },
    }


def sds_candidates(ctx: Context) -> tuple[Candidate, ...]:
    """The SDS catalog candidates for this record."""
    M = ctx.consts["psi_m"].size
    pp = int(ctx.meta.get("encoder", {}).get("pole_pairs", 0) or 0)
    return _catalog(M, pp)


@functools.lru_cache(maxsize=16)
def _catalog(M: int, pp: int) -> tuple[Candidate, ...]:
    """One set of candidate objects per layout (one compiled Jacobian each). Every
    candidate but the delay step is refused when one run's deviation on one sensor
    dominates the base residual (:func:`_transient`): a smooth pattern in the platform
    angle or in time would only take a part of that transient."""
    out = [
        Candidate(
            "axis_tilt",
            _axis_tilt_fn,
            (
                Param("tilt_rad", "rad", linear=False, scale=1e-3),
                Param("azimuth_rad", "rad", linear=False, scale=0.3),
            ),
            signature=("sds_axis_tilt", "orders"),
            kinds=("sds",),
            explanation=EXPLANATIONS["axis_tilt"],
            start=_tilt_start,
            plausible=_no_transient(),
            derived=_tilt_derived,
        ),
        Candidate(
            "thermal_drift",
            _drift_fn,
            (Param("drift_rate_rad_per_s", "rad/s"),),
            signature=("sds_thermal_drift", "run_step"),
            kinds=("sds",),
            explanation=EXPLANATIONS["thermal_drift"],
            applies=_no_ref_drift,
            plausible=_no_transient(_drift_plausible),
        ),
        Candidate(
            "bearing_wobble",
            _wobble_fn,
            (
                Param("frequency_ratio", "1", linear=False, scale=0.01),
                Param("sin_rad", "rad"),
                Param("cos_rad", "rad"),
                Param("first_run", "1", linear=False, fit=False),
            ),
            signature=("sds_bearing_wobble",),
            kinds=("sds",),
            explanation=EXPLANATIONS["bearing_wobble"],
            start=_wobble_start,
            plausible=_no_transient(),
            derived=_wobble_derived,
        ),
        Candidate(
            "beam_tilt_axial",
            _beam_fn,
            (
                Param("cos_rad", "rad", (len(BEAM_ORDERS),)),
                Param("sin_rad", "rad", (len(BEAM_ORDERS),)),
            ),
            signature=("sds_beam_tilt_axial", "common_orders"),
            kinds=("sds",),
            explanation=EXPLANATIONS["beam_tilt_axial"],
            applies=_no_ref_beam,
            plausible=_no_transient(_beam_plausible),
            derived=_beam_derived,
        ),
        Candidate(
            "sensor_delay_step",
            _delay_fn,
            (
                Param("delay_s", "s", (M,), scale=1e-10),
                Param("first_run", "1", linear=False, fit=False),
            ),
            signature=("run_step",),
            kinds=("sds",),
            explanation=EXPLANATIONS["sensor_delay_step"],
            start=_delay_start,
            plausible=_delay_plausible,
            derived=_delay_derived,
        ),
    ]
    if pp > 1:
        orders = tuple(range(1, pp))
        coil = _ripple_term(orders, "coil_mismatch", EXPLANATIONS["coil_mismatch"])
        out.append(
            dataclasses.replace(
                coil,
                plausible=_no_transient(_coil_plausible),
                signature=("sds_coil_mismatch", "run_step"),
            )
        )
    return tuple(out)


# ----------------------------------------------------------------------------- views


def view_run_step(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """Per moving sensor (run-mean channels), the best step over the runs in time order and
    the strongest single-run outlier; 1 dof each, Bonferroni over sensors x positions."""
    M = prep.consts["psi_m"].size
    r = rw[:, :M]
    R = r.shape[0]
    n_tests = max(1, 2 * M * (R - 1))
    thr = _thr(1, n_tests)
    out = []
    for m in range(M):
        x = r[:, m] - r[:, m].mean()
        best = (0.0, 1, "step")
        for k in range(1, R):
            s = (np.arange(R) >= k).astype(float)
            s -= s.mean()
            pw = float((s @ x) ** 2 / (s @ s))
            if pw > best[0]:
                best = (pw, k, "step")
        j = int(np.argmax(np.abs(x)))
        pw_out = float(x[j] ** 2 * R / (R - 1))
        if pw_out > best[0]:
            best = (pw_out, j, "run_outlier")
        if best[0] > thr:
            k = best[1]
            out.append(
                Finding(
                    "run_step",
                    _where(
                        heads=[m],
                        runs=[int(prep.run_ids[k])],
                        times_s=[float(prep.rows["t"][k])],
                    ),
                    best[0],
                    1,
                    _logp(best[0], 1),
                    detail={
                        "shape": best[2],
                        "first_run_index": int(k),
                        "sensor": f"m{m}",
                        "n_values": int(R),
                    },
                )
            )
    return out


def _matched_view(name: str):
    """A view: the power the candidate's columns (at its start) take out of the residual."""

    def view(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
        ctx = prep.ctx
        cands = {c.name: c for c in sds_candidates(ctx)}
        if name not in cands:
            return []
        cand = cands[name]
        if cand.applies is not None and cand.applies(ctx):
            return []
        x = _jx(ctx)
        resid = rw * prep.sigma[None, :]
        starts = cand.start(ctx, resid, []) if cand.start else [{}]
        best = (0.0, 0)
        for st in starts:
            p = {}
            for q in cand.params:
                shp = q.resolved_shape(ctx.n_channels, ctx.n_runs)
                v0 = st.get(q.name)
                p[q.name] = jnp.asarray(np.zeros(shp) if v0 is None else v0, float)
            free = [q.name for q in cand.params if q.fit]
            _, J = _valjac_fn(cand)(p, x)
            cols = (
                np.concatenate([np.asarray(J[k]).reshape(*rw.shape, -1) for k in free], axis=-1)
                / prep.sigma[None, :, None]
            )
            pw = _ls_power_flat(rw, cols)
            q_eff = int(np.linalg.matrix_rank(cols.reshape(-1, cols.shape[-1]), tol=None))
            if pw > best[0]:
                best = (pw, max(q_eff, 1))
        pw, q = best
        n_starts = (
            len(_wobble_grid(ctx)) * len(_wobble_onsets(int(ctx.n_runs)))
            if name == "bearing_wobble"
            else max(len(starts), 1)
        )
        thr = _thr(q, 6 * n_starts)
        if pw <= thr:
            return []
        return [
            Finding(
                f"sds_{name}",
                _where(heads=list(range(prep.n_channels)), runs=prep.run_ids.tolist()),
                pw,
                q,
                _logp(pw, q),
                detail={"n_values": int(rw.size), "candidate": name},
            )
        ]

    return view


def view_mean_orders(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """The engine's ``orders`` view on the run-mean channels only (a pattern in the platform
    angle is constant within a run: it cannot reach the revolution contrasts, whose
    scan would only add false alarms)."""
    from ._views import view_orders

    M = prep.consts["psi_m"].size
    r = np.zeros_like(rw)
    r[:, :M] = rw[:, :M]
    return view_orders(prep, r, min(scan_order, sds_limit(prep)))


# the run-step view first: findings are ranked by p-value, which floors at 1e-999 for a
# strong structure; among equals the most specific location (one sensor, one run) leads
SDS_VIEWS = (
    view_run_step,
    view_mean_orders,
    view_common_orders,
    _matched_view("axis_tilt"),
    _matched_view("thermal_drift"),
    _matched_view("bearing_wobble"),
    _matched_view("beam_tilt_axial"),
    _matched_view("coil_mismatch"),
)


# ----------------------------------------------------------------------------- base


def sds_limit(prep: Prepared) -> int:
    """Highest order in ``x = φ + ψ_m`` the record resolves: ``R·M/2 − 1``."""
    M = prep.consts["psi_m"].size
    return int(max(1, prep.ctx.n_runs * M // 2 - 1))


def _common_x_orders(prep: Prepared, orders) -> list[int]:
    """Orders ``n`` in ``x = φ + ψ_m`` whose columns vanish on the moving-sensor differences
    (``n ψ_m`` equal mod 2π for every sensor) when the record is projected (no phi_ref)."""
    if float(prep.consts["proj"]) <= 0:
        return []
    psi = np.asarray(prep.consts["psi_m"], float)
    out = []
    for n in orders:
        z = np.exp(1j * n * psi)
        if np.max(np.abs(z - z.mean())) < 1e-9:
            out.append(int(n))
    return out


def sds_base(prep: Prepared, max_order: int):
    """Pair constants plus the design's ripple orders (see module doc)."""
    enc = prep.ctx.meta.get("encoder", {})
    M = prep.consts["psi_m"].size
    p = int(enc.get("pole_pairs", 0) or 0)
    orders = (
        _design_orders(p, enc.get("stator_coils"), enc.get("commutation_states"), max_order)
        if p > 0
        else []
    )
    terms = [(_const_term(M), {})]
    common_x = _common_x_orders(prep, orders)
    if common_x:
        # without phi_ref an order with one phase at every moving sensor is taken by the
        # per-run offset: its projected columns are zero up to rounding, which a normalised
        # solve would fit as if they carried information; left out and listed
        orders = [o for o in orders if o not in common_x]
    if orders:
        terms.append((_ripple_term(tuple(orders)), {}))
    has_ref = prep.ctx.has_ref
    prep.consts["base_orders"] = orders  # type: ignore[index]
    unid = [
        "the constant offset (instrument zero): its physical causes cannot be told apart",
    ]
    if not has_ref:
        unid += [
            "no phi_ref: the absolute platform angle of each run (a per-run offset is "
            "taken out), so the common constant of the moving sensors is held",
            "no phi_ref: anything common to the moving sensors of a run (beam tilt x axial "
            f"runout, orders that are multiples of {M} in x, a common drift across runs)",
        ]
        common = [n for n in range(1, p) if n % M == 0 and M > 1]
        if common:
            unid.append(
                f"no phi_ref: coil_mismatch orders {common} have one phase at every moving "
                "sensor (multiples of the moving-sensor count): held as unidentifiable"
            )
    if common_x:
        unid.append(
            f"no phi_ref: design orders {common_x} have one phase at every moving sensor "
            "(taken by the per-run offset): left out of the base model"
        )
    info = {
        "design_orders": orders,
        "pole_pairs": p,
        "n_revolutions_per_run": int(prep.kd.n_revs),
        "revolutions_left_out": int(prep.kd.dropped_revs),
        "radius_m": float(prep.kd.radius_m or REFERENCE_RADIUS_M),
        "unidentifiable": unid,
    }
    return terms, info


def sds_summary(prep: Prepared, base_params: dict) -> dict:
    """The clock block: the stamp lattice found in the data against the declared clock."""
    kd = prep.kd
    lat = dict(kd.lattice or {})
    P = lat.get("period_s")
    T = kd.table.period_s
    N = kd.table.n_marks
    floor = None
    if P is not None:
        # uniform stamp error (var P^2/12) on the 2N window edges of a pair: seed 001 eq. 23
        floor = 2 * math.pi * P / (T * math.sqrt(6 * N))
    ratio = P / kd.declared_clock_s if (P is not None and kd.declared_clock_s) else None
    return {
        "clock": {
            "declared_period_s": kd.declared_clock_s,
            "lattice_period_s": P,
            "ratio_to_declared": ratio,
            "fraction_on_lattice": lat.get("fraction_on_lattice"),
            "predicted_floor_rad": floor,
            "method": lat.get("method"),
        },
        "grid_period_s": P,
        "noise_estimate": dict(prep.ctx.consts.get("noise_info") or {}),
        "drift_vs_orders": prep.ctx.consts.get("drift_vs_orders"),
    }


SDS = Kind(
    name="sds",
    data=sds_data,
    base=sds_base,
    candidates=sds_candidates,
    views=SDS_VIEWS,
    max_order_limit=sds_limit,
    default_max_order=60,
    summary=sds_summary,
    prepare=sds_prepare,
    noise=sds_noise,
    noise_replaces=True,
)


# ----------------------------------------------------------------------------- finish


NOISE_METHOD = (
    "run means: residual of a saturated least-squares fit of the base residual (smooth "
    "patterns in the platform angle, drift, significant change points and single-value "
    "outliers), sqrt(SSR / dof) with dof = independent values - rank (R(M-1) values without "
    "phi_ref), widened by sqrt(q F(q, dof) / chi2(q)) at p = 1e-4 for its estimation error "
    "(estimate, dof and factor under 'estimate'); revolution contrasts: 1.4826 MAD, the larger "
    "of the parts common to the moving sensors and their differences"
)


def finish_sds(doc: dict) -> dict:
    """SDS additions to the engine's document: ``timing_quantization`` named from the stamp
    lattice (a floor, not a fitted term), the quantization floor in the goodness of fit,
    honest standard errors (scaled by the final variance ratio when it exceeds 1; the
    azimuth of an unresolved tilt is unidentifiable), and no non-finite number anywhere."""
    clock = doc.get("clock", {})
    est = doc.pop("noise_estimate", None)
    if isinstance(doc.get("noise"), dict):
        doc["noise"]["method"] = NOISE_METHOD
        if est:
            doc["noise"]["estimate"] = est
    gof = doc.get("goodness_of_fit") or {}
    vr = float(gof.get("variance_ratio", 1.0) or 1.0)
    scale = math.sqrt(max(vr, 1.0))
    noise = doc.get("noise", {}).get("per_channel", [])
    floor = clock.get("predicted_floor_rad")
    if isinstance(gof, dict):
        gof["quantization"] = {
            "lattice_period_s": clock.get("lattice_period_s"),
            "predicted_floor_rad": floor,
            "noise_run_means_rad": noise[0] if noise else None,
            "note": "the noise levels are estimated from the data and so include the "
            "quantization of the stamps on the lattice found; the predicted floor "
            "2 pi P / (T sqrt(6 N)) is what a perfect bench on that lattice would show",
        }
    dv = doc.pop("drift_vs_orders", None)
    for e in doc.get("effects", []):
        if e["name"] == "thermal_drift" and dv:
            lim = math.log(max(dv["n_values"], 2))
            if dv["order_power"] >= dv["drift_power"] - lim:
                # within one parameter's worth: the data cannot tell the two apart
                e["confounded_with"] = [
                    *(e.get("confounded_with") or []),
                    {
                        "name": f"platform_angle_order_{dv['order']}",
                        "reason": f"order {dv['order']} of the platform angle, common to the "
                        f"moving sensors, fits the base residual nearly as well (chi-square "
                        f"{dv['order_power']:.1f}, 2 dof, vs the drift's "
                        f"{dv['drift_power']:.1f}, 1 dof; correlation "
                        f"{dv['correlation']:.2f}): with this platform stepping it is nearly "
                        "a trend over the runs",
                        "delta_bic": None,
                        "params": {},
                    },
                ]
                e["notes"] = [
                    *e.get("notes", []),
                    f"confounded with order {dv['order']} of the platform angle (out of "
                    "catalog): this recording cannot tell a drift in time from it; step the "
                    "platform in another order or repeat positions to separate them",
                ]
        for q in e.get("params", {}).values():
            if isinstance(q.get("se"), list | float | int) and scale > 1:
                q["se"] = _scale(q["se"], scale)
        if e["name"] == "axis_tilt":
            p = e["params"]
            # (tilt, azimuth) and (-tilt, azimuth + pi) are one tilt: report tilt >= 0 and
            # the azimuth in [0, pi)
            if p["tilt_rad"]["value"] < 0:
                p["tilt_rad"]["value"] = -p["tilt_rad"]["value"]
            p["azimuth_rad"]["value"] = float(np.mod(p["azimuth_rad"]["value"], np.pi))
            b, sb = abs(p["tilt_rad"]["value"]), p["tilt_rad"]["se"]
            if sb is None or not b > 3 * sb:
                p["azimuth_rad"]["se"] = None
                e["notes"] = [
                    *e.get("notes", []),
                    "the tilt is not resolved (|tilt| <= 3 se): its azimuth is unidentifiable",
                ]
    ratio = clock.get("ratio_to_declared")
    if ratio is not None and ratio > LATTICE_COARSER:
        rms = doc.get("rms_final", doc.get("rms_before"))
        doc["effects"].append(
            {
                "name": "timing_quantization",
                "params": {
                    "clock_period_s": {
                        "value": clock["lattice_period_s"],
                        "se": None,
                        "unit": "s",
                    },
                    "declared_period_s": {
                        "value": clock["declared_period_s"],
                        "se": None,
                        "unit": "s",
                    },
                    "predicted_floor_rad": {"value": floor, "se": None, "unit": "rad"},
                },
                "derived": {},
                "channels": None,
                "rms_after": rms,
                "heldout_rms_after": doc.get("heldout_rms_final"),
                "delta_bic": None,
                "collinearity": None,
                "share": 0.0,
                "notes": [
                    f"every stamp lies on a {clock['lattice_period_s']:.4g} s lattice, "
                    f"{ratio:.3g} x the declared clock period; named from the lattice, not "
                    "fitted (a noise floor): delta_bic and collinearity do not apply"
                ],
                "explanation": EXPLANATIONS["timing_quantization"],
            }
        )
        if doc["verdict"] == "consistent":
            doc["verdict"] = "missing_physics"
    elif clock.get("lattice_period_s") is None and clock.get("declared_period_s"):
        doc["notes"].append(
            "no stamp lattice found in the data although a clock is declared: the stamps "
            "look continuous (interpolated or free-running time)"
        )
    return _finite(doc)


def _scale(v, s):
    if isinstance(v, list):
        return [_scale(x, s) for x in v]
    return None if v is None else float(v) * s


def _finite(v):
    """Non-finite numbers become ``None`` (the JSON has no NaN)."""
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_finite(x) for x in v]
    if isinstance(v, float | np.floating) and not math.isfinite(float(v)):
        return None
    return v
