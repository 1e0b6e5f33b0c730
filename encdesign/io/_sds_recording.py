"""``sds`` recordings: simulate edge times into a recording, read them back into φ.

A recording of kind ``sds`` (``docs/recording-format.md``) holds, per run (one platform
position), the edge times of every sensor: columns ``run``, ``phi_ref`` (optional),
``sensor`` (``f0…`` fixed, ``m0…`` moving), ``mark`` (index from the index pulse) and ``t``
(s). The deeper checks of the kind (:mod:`encdesign.io._sds_format`) run in
``load_recording`` for every ``sds`` file.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import input_error
from ..physics._sds import SDSDesign, edge_times, sds_from_edges, validate_design
from ..physics._sds_errors import SDSErrors
from ._recording import Recording, write_recording
from ._sds_format import _sensor_counts, check_sds_columns  # noqa: F401 (re-exported)

__all__ = [
    "SDSRecordingResult",
    "check_sds_columns",
    "sds_readings_from_recording",
    "simulate_sds_recording",
]


_edge_times_jit = jax.jit(edge_times, static_argnums=(2,), static_argnames=("n_newton",))
_sds_jit = jax.jit(sds_from_edges)


# ----------------------------------------------------------------------------- write


def simulate_sds_recording(
    path: str | os.PathLike,
    design: SDSDesign,
    phi_rad: Any,
    n_revs: int,
    errors: SDSErrors | None = None,
    *,
    key: jax.Array | None = None,
    description: str | None = None,
    compress: bool = False,
    n_newton: int = 2,
) -> Recording:
    """Simulate a bench run and write it as an ``sds`` recording (TOML + CSV).

    Each platform angle is one run: ``n_revs + 1`` revolutions of every sensor, all
    sensors' edges merged in time order. Runs follow each other in time (``n_revs + 2``
    revolutions apart), so drifts continue across runs.

    Args:
        path: output TOML path (the CSV goes beside it; written atomically).
        design, errors: instrument and error physics.
        phi_rad: platform angles, one per run, rad.
        n_revs: complete readings wanted per run (>= 1).
        key: ``jax.random`` key for jitter (``None``: no jitter).
        description: free text for the TOML.
        compress: write ``.csv.gz``.
        n_newton: Newton iterations for the edge times.

    Returns:
        The :class:`~encdesign.Recording` as written.
    """
    errors = SDSErrors() if errors is None else errors
    validate_design(design, errors)
    if isinstance(n_revs, bool) or not isinstance(n_revs, int) or n_revs < 1:
        raise input_error("simulate_sds_recording n_revs", f"got {n_revs!r}", ">= 1")
    phis = np.atleast_1d(np.asarray(phi_rad, dtype=float))
    n_marks = design.marks_per_rev
    names = [f"f{i}" for i in range(design.n_fixed)] + [f"m{i}" for i in range(design.n_moving)]
    key = jax.random.PRNGKey(0) if key is None else key  # jitter_s = 0: no effect
    cols: dict[str, list[np.ndarray]] = {c: [] for c in ("run", "phi_ref", "sensor", "mark", "t")}
    for i, phi in enumerate(phis):
        f, m = _edge_times_jit(
            design,
            jnp.asarray(phi),
            n_revs + 1,
            errors,
            key=jax.random.fold_in(key, i),
            first_rev=jnp.asarray(i * (n_revs + 2), float),
            n_newton=n_newton,
        )
        times = np.concatenate([np.asarray(f), np.asarray(m)], axis=0)  # (S, R, N)
        s_count, r_count, _ = times.shape
        t = times.reshape(-1)
        sensor = np.repeat(np.asarray(names), r_count * n_marks)
        mark = np.tile(np.arange(n_marks), s_count * r_count)
        order = np.argsort(t, kind="stable")
        cols["t"].append(t[order])
        cols["sensor"].append(sensor[order])
        cols["mark"].append(mark[order])
        cols["run"].append(np.full(t.size, i, dtype=np.int64))
        cols["phi_ref"].append(np.full(t.size, float(np.mod(phi, 2 * np.pi))))
    # one column at a time, each run's pieces freed as soon as they are joined
    data = {k: np.concatenate(cols.pop(k)) for k in list(cols)}
    deg = 180.0 / math.pi
    encoder: dict[str, Any] = {
        "marks_per_rev": n_marks,
        "fixed_sensor_angles_deg": [float(x) * deg for x in np.asarray(design.fixed_azimuths_rad)],
        "moving_sensor_angles_deg": [
            float(x) * deg for x in np.asarray(design.moving_azimuths_rad)
        ],
        "pole_pairs": design.pole_pairs,
        "stator_coils": design.stator_coils,
        "commutation_states": design.commutation_states,
    }
    if float(errors.clock_period_s) > 0:
        encoder["clock_hz"] = 1.0 / float(errors.clock_period_s)
    return write_recording(
        path,
        "sds",
        data,
        encoder=encoder,
        description=description or "simulated shifted-delta-sum bench run (encdesign)",
        provenance={"simulated_by": "encdesign.simulate_sds_recording", "n_revs": n_revs},
        compress=compress,
    )


# ----------------------------------------------------------------------------- read


@dataclasses.dataclass(frozen=True)
class SDSRecordingResult:
    """φ measured from an ``sds`` recording, per run.

    Attributes:
        runs: run ids, shape (R,).
        phi_rad: measured φ per run (wrap-safe mean of its readings), rad, in (−π, π].
        readings_rad: list of arrays, the readings of each run, rad.
        phi_ref_rad: reference φ per run, rad, or ``None`` when the table has no phi_ref.
        error_rad: ``wrap(φ − phi_ref)`` per run, rad, or ``None``.
        error_zeroed_rad: ``error − error[0]`` (instrument zeroed at the first run), or
            ``None``. The absolute error contains the unknown mean mark errors of the two
            disks; zeroing removes that constant, as on the real instrument.
    """

    runs: np.ndarray
    phi_rad: np.ndarray
    readings_rad: list[np.ndarray]
    phi_ref_rad: np.ndarray | None
    error_rad: np.ndarray | None
    error_zeroed_rad: np.ndarray | None


def _wrap_np(x):
    return np.mod(np.asarray(x) + np.pi, 2 * np.pi) - np.pi


def _circ_mean(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Mean of angles that are close to each other, wrap-safe, in (−π, π]."""
    ref = np.take(x, [0], axis=axis)
    return _wrap_np(np.squeeze(ref, axis) + np.mean(_wrap_np(x - ref), axis=axis))


def _window(t: np.ndarray, m: np.ndarray, anchor: float, n_marks: int, need_next: bool):
    """N consecutive edges from the first at/after ``anchor``: (times by mark, k, period)."""
    i = int(np.searchsorted(t, anchor))
    if i + n_marks + (1 if need_next else 0) > len(t):
        return None
    win_t, win_m = t[i : i + n_marks], m[i : i + n_marks]
    by_mark = np.empty(n_marks)
    by_mark[win_m] = win_t
    k = int(np.flatnonzero(win_m == 0)[0])
    period = float(t[i + n_marks] - t[i]) if need_next else 0.0
    return by_mark, k, period


def _run_windows(where: str, run: int, times: dict, marks: dict, n_marks: int, nf: int, nm: int):
    """Edge windows of every complete reading of one run, aligned in time.

    Readings start at edges of f0 spaced by N edges, beginning at the first f0 edge at or
    after the latest first edge of any sensor: every sensor's window then starts within one
    mark spacing of the others, so the windows cover the same revolution (a sensor whose
    edges begin later would otherwise read a window shifted by up to one revolution, which
    does not cancel errors that change from one revolution to the next).
    """
    tf0 = times["f0"]
    names = [f"f{f}" for f in range(nf)] + [f"m{m}" for m in range(nm)]
    t_start = max(float(times[s][0]) for s in names)
    first = int(np.searchsorted(tf0, t_start))
    alphas, periods, kfs, taus, kms = [], [], [], [], []
    for s in range(first, len(tf0), n_marks):
        anchor = tf0[s]
        fixed = [_window(times[f"f{f}"], marks[f"f{f}"], anchor, n_marks, True) for f in range(nf)]
        moving = [
            _window(times[f"m{m}"], marks[f"m{m}"], anchor, n_marks, False) for m in range(nm)
        ]
        if any(w is None for w in fixed + moving):
            break
        alphas.append(np.stack([w[0] for w in fixed]))
        kfs.append([w[1] for w in fixed])
        periods.append([w[2] for w in fixed])
        taus.append(np.stack([w[0] for w in moving]))
        kms.append([w[1] for w in moving])
    if not alphas:
        raise input_error(
            f"{where}, run {run}",
            "no complete revolution for all sensor pairs",
            f"every sensor to cover at least one full revolution ({n_marks} edges) after "
            "the first edge of the sensor that starts last, the fixed sensors one edge more",
        )
    return (
        np.stack(alphas),
        np.asarray(periods),
        np.asarray(kfs),
        np.stack(taus),
        np.asarray(kms),
    )


def sds_readings_from_recording(rec: Recording, *, revs_per_reading: int = 1) -> SDSRecordingResult:
    """Measure φ from an ``sds`` recording: SDS per fixed × moving pair, averaged.

    Each reading starts at an edge of fixed sensor f0 once every sensor has begun (so all
    windows cover the same revolution); every sensor contributes its next N edges (seed
    eqs. 23–24, k = pos(B_0) − pos(A_0)); the pair constants are the
    nominal azimuth differences from the TOML; ``revs_per_reading`` consecutive
    revolutions are averaged.

    Raises:
        EncdesignInputError: not an ``sds`` recording, a run without a complete revolution.
    """
    where = str(rec.path) if rec.path is not None else "<recording>"
    if rec.kind != "sds":
        raise input_error(where, f"kind {rec.kind!r}", "a recording of kind 'sds'")
    if isinstance(revs_per_reading, bool) or revs_per_reading < 1:
        raise input_error("revs_per_reading", f"got {revs_per_reading!r}", ">= 1")
    check_sds_columns(where, rec.meta, rec.columns)  # also for in-memory recordings
    n_marks, nf, nm = _sensor_counts(rec.meta)
    enc = rec.encoder
    psi_f = np.radians(np.asarray(enc["fixed_sensor_angles_deg"], dtype=float))
    psi_m = np.radians(np.asarray(enc["moving_sensor_angles_deg"], dtype=float))
    offsets = jnp.asarray(psi_m[None, :] - psi_f[:, None])
    cols = rec.columns
    run = rec.runs
    runs, phis, readings, refs = [], [], [], []
    for r in np.unique(run):
        sel = run == r
        sens, mk, t = cols["sensor"][sel], cols["mark"][sel], cols["t"][sel]
        times, marks = {}, {}
        for name in [f"f{i}" for i in range(nf)] + [f"m{i}" for i in range(nm)]:
            s = sens == name
            if not np.any(s):
                raise input_error(f"{where}, run {int(r)}", f"no edges of sensor {name}")
            times[name], marks[name] = t[s], mk[s]
        alpha, period, k_f, tau, k_m = _run_windows(where, int(r), times, marks, n_marks, nf, nm)
        pair = np.asarray(_sds_jit(alpha, period, k_f, tau, k_m, offsets))  # (R, F, M)
        if not np.all(np.isfinite(pair)):
            raise input_error(f"{where}, run {int(r)}", "non-finite SDS result", "finite times")
        per_rev = _circ_mean(pair.reshape(pair.shape[0], -1), axis=1)
        n_read = len(per_rev) // revs_per_reading
        if n_read == 0:
            raise input_error(
                f"{where}, run {int(r)}",
                f"{len(per_rev)} complete revolution(s)",
                f"at least revs_per_reading = {revs_per_reading}",
            )
        grouped = per_rev[: n_read * revs_per_reading].reshape(n_read, revs_per_reading)
        rd = _circ_mean(grouped, axis=1)
        runs.append(int(r))
        readings.append(rd)
        phis.append(float(_circ_mean(rd)))
        if "phi_ref" in cols:
            refs.append(float(cols["phi_ref"][sel][0]))
    phi = np.asarray(phis)
    if refs:
        ref = np.asarray(refs)
        err = _wrap_np(phi - ref)
        zeroed = err - err[0]
    else:
        ref = err = zeroed = None
    return SDSRecordingResult(
        runs=np.asarray(runs),
        phi_rad=_wrap_np(phi),
        readings_rad=readings,
        phi_ref_rad=ref,
        error_rad=err,
        error_zeroed_rad=zeroed,
    )
