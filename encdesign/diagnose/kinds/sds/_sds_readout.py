"""The instrument's readout of an ``sds`` recording: edge times into φ per run.

A recording of kind ``sds`` (``docs/recording-format.md``) holds, per run (one platform
position), the edge times of every sensor. :func:`sds_readings_from_recording` windows each
run into complete revolutions (:func:`run_windows`) and applies the shifted delta sum (seed
eqs. 23-24, :func:`encdesign.physics.sds_from_edges`) per fixed x moving pair. The finder's
``sds`` kind (``_sds``) and ``encdesign sds read`` both use it; the simulator that writes such
recordings is :func:`encdesign.simulate.simulate_sds_recording`.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ...._errors import input_error
from ....io._recording import Recording
from ....io._sds_format import check_sds_columns, sensor_counts
from ....physics._sds import sds_from_edges

__all__ = ["SDSRecordingResult", "run_windows", "sds_jit", "sds_readings_from_recording"]

sds_jit = jax.jit(sds_from_edges)
""":func:`~encdesign.physics.sds_from_edges`, jitted once for every caller."""


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


def run_windows(where: str, run: int, times: dict, marks: dict, n_marks: int, nf: int, nm: int):
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
    n_marks, nf, nm = sensor_counts(rec.meta)
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
        alpha, period, k_f, tau, k_m = run_windows(where, int(r), times, marks, n_marks, nf, nm)
        pair = np.asarray(sds_jit(alpha, period, k_f, tau, k_m, offsets))  # (R, F, M)
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
