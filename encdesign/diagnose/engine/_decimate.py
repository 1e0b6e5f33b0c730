"""Issue 43 (session 32): stage 2 of a long record's reduction, a linear-phase FIR low-pass
and decimation by an integer factor ``R`` of the block means (:mod:`._reduce`, stage 1).

The block means keep the record's rate divided by ``B`` (about 4 kHz for 50 kHz rows), far
above ``f_needed_hz``, the highest frequency any view or candidate needs (about 100 Hz): the
boxcar's passband is not flat, so ``B`` cannot grow. Stage 2 filters the block means with a
symmetric FIR of ``2 h + 1`` taps (:func:`design`) and keeps every ``R``-th output, so the
engine sees rows at ``rate_out_hz`` = :data:`RATE_OVER_NEEDED` x ``f_needed_hz`` or a little
more (``R`` the largest integer for it, at most ``FinderSettings.reduce_decimation_max``).

**The bound holds for both stages together.** With stage 2 on, the block takes half of
``FinderSettings.reduce_attenuation_max`` (``block_attenuation_max``) and the filter the
rest: at every frequency up to ``f_needed_hz`` the combined gain ``D(f) |H(f)|`` is within
``reduce_attenuation_max`` of 1 (checked on a grid of :data:`CHECK_POINTS` frequencies, the
taps grown until it holds). The filter is symmetric, so its phase is linear: an output row
stands at the time of its centre tap's row (``t`` is that row's, exact for a linear ``t``).
``orders_kept`` is what the two stages together keep within the bound.

**White noise stays white.** The amplitude is a root-raised-cosine (square-root Nyquist)
response: 1 up to ``passband_hz`` = ``f_needed_hz``, ``cos(pi/2 u)`` across the transition
(``u`` from 0 at ``passband_hz`` to 1 at ``stopband_hz`` = ``rate_out_hz - passband_hz``),
0 above; so ``|H(f)|^2 + |H(rate_out - f)|^2 = 1`` across the transition band, and the
noise decimation folds onto the output band adds up to a flat spectrum (variance ``1 / R``
of the input's for white noise; the engine's noise level, taken from the reduced rows, and
its chi-square tests stay calibrated). Designed with ``scipy.signal.firwin2`` (a Kaiser
window, :data:`KAISER_BETA`); the largest departure from power complementarity over the
transition band is stated (``power_complementary_error``, at most :data:`PC_ERROR_MAX`).

**Stretches.** A stretch of the block means ends at a new run, a gap in ``t`` over
``GAP_STEPS`` reduced steps (a block left out), a reversal or a jump of a reading over half a
turn (:func:`._reduce.stretch_starts` on the reduced columns). Outputs lie on one fixed grid
of the stage-1 rows (centres ``h + k R``); only those whose whole window lies in one stretch
are kept (``run`` is constant there), and the rows left out are counted. Stage 2 runs on the
whole stage-1 record that every process holds after the gather; on several processes each
filters a contiguous share of the output chunks (:data:`OUT_CHUNK` outputs each, the same
chunks as on one process: :func:`chunk_share`) and the filtered columns are gathered, so one
process and several give the same document bit for bit.

Where ``R`` would be under 2, or fewer than :data:`MIN_ROWS_OUT` outputs would be left (short
or few stretches for the filter), stage 2 is not applied
(``decimation.applied`` false, with the reason) and the block alone carries the bound. Lines
above ``passband_hz`` (attenuated, and those between ``rate_out_hz / 2`` and
``stopband_hz`` folded into the band) cannot be tested on the decimated record: its diagnosis
says so (``not_testable``).
"""

from __future__ import annotations

import math

import jax
import numpy as np

from ..._distributed import allgather_concat, split_range
from ...io._recording import KINDS as SPECS
from ...io._recording import Recording
from ._noise import NOISE_BAND_KEY
from ._reduce import (
    MIN_ROWS_OUT,
    RATE_OVER_NEEDED,
    attenuation,
    decimation_factor,
    shaft_of,
    stretch_starts,
)
from ._rowshare import is_alone
from ._settings import FinderSettings

KAISER_BETA = 6.0
"""The Kaiser window's ``beta`` of the FIR design (``firwin2``)."""

PC_ERROR_MAX = 0.01
"""The largest departure from ``|H(f)|^2 + |H(rate_out - f)|^2 = 1`` allowed (the taps grow
until the design meets it and the passband bound)."""

TAPS_PER_TRANSITION = 8.0
"""The first design's taps: this many times the input rate over the transition width."""

TAPS_GROWTH = 1.25
"""Each design that misses the bound is followed by one with this many times its taps."""

STOP_CHECK_POINTS = 2048
"""Frequencies on which the stopband's largest gain is stated."""

TAPS_MAX = 1 << 14
"""No more taps than this (a design that needs more is not applied)."""

CHECK_POINTS = 512
"""Frequencies on which the passband bound and the power complementarity are checked."""

OUT_CHUNK = 2048
"""Outputs computed at a time (bounded temporaries: ``OUT_CHUNK`` x taps)."""


def rrc_amplitude(f: np.ndarray, f_pass: float, f_stop: float) -> np.ndarray:
    """The root-raised-cosine amplitude: 1 up to ``f_pass`` (Hz), ``cos(pi/2 u)`` across the
    transition (``u`` from 0 at ``f_pass`` to 1 at ``f_stop``), 0 above."""
    u = np.clip((np.asarray(f, float) - f_pass) / (f_stop - f_pass), 0.0, 1.0)
    return np.cos(0.5 * math.pi * u)


def _gain(taps: np.ndarray, f: np.ndarray, fs: float) -> np.ndarray:
    """``|H(f)|`` of the FIR ``taps`` at rate ``fs`` (Hz)."""
    from scipy.signal import freqz

    return np.abs(freqz(taps, worN=np.asarray(f, float), fs=fs)[1])


def design(fs_in: float, dt: float, B: int, f_need: float, R: int, tol: float) -> dict:
    """The stage-2 filter for block means of ``B`` rows sampled every ``dt`` s (input rate
    ``fs_in`` Hz), decimated by ``R``: ``taps`` (an odd number, symmetric, summing to 1) and
    their description. Taps grow from :data:`TAPS_PER_TRANSITION` x ``fs_in`` over the
    transition width until the block and the filter together keep every frequency up to
    ``f_need`` within ``tol`` of unit gain and the power complementarity holds within
    :data:`PC_ERROR_MAX`; ``taps`` is ``None`` when :data:`TAPS_MAX` do not."""
    from scipy.signal import firwin2

    fs_out = fs_in / R
    f_stop = fs_out - f_need
    f = np.linspace(0.0, f_need, CHECK_POINTS)
    D = np.array([1.0 - attenuation(x, dt, B) for x in f])
    ft = np.linspace(f_need, 0.5 * fs_out, CHECK_POINTS)
    n = int(math.ceil(TAPS_PER_TRANSITION * fs_in / (f_stop - f_need))) | 1
    while True:
        nf = 1 + 2 ** int(math.ceil(math.log2(8 * n)))
        grid = np.linspace(0.0, 0.5 * fs_in, nf)
        taps = firwin2(
            n, grid, rrc_amplitude(grid, f_need, f_stop), nfreqs=nf,
            window=("kaiser", KAISER_BETA), fs=fs_in,
        )  # fmt: skip
        taps = 0.5 * (taps + taps[::-1])  # exactly symmetric (linear phase)
        taps = taps / taps.sum()  # unit gain at 0 Hz
        dev = float(np.max(np.abs(D * _gain(taps, f, fs_in) - 1.0)))
        pc = _gain(taps, ft, fs_in) ** 2 + _gain(taps, fs_out - ft, fs_in) ** 2
        pc_err = float(np.max(np.abs(pc - 1.0)))
        if dev <= tol and pc_err <= PC_ERROR_MAX:
            break
        if n >= TAPS_MAX:
            return {"taps": None, "n_taps": n, "combined_deviation": dev}
        n = min(TAPS_MAX, int(TAPS_GROWTH * n)) | 1
    ripple = float(np.max(np.abs(_gain(taps, f, fs_in) - 1.0)))
    stop = float(np.max(_gain(taps, np.linspace(f_stop, 0.5 * fs_in, STOP_CHECK_POINTS), fs_in)))
    return {
        "taps": taps,
        "n_taps": int(n),
        "passband_hz": float(f_need),
        "stopband_hz": float(f_stop),
        "rate_in_hz": float(fs_in),
        "rate_out_hz": float(fs_out),
        "ripple": ripple,
        "stopband_gain_max": stop,
        "combined_deviation": dev,
        "power_complementary_error": pc_err,
    }


def combined_orders_kept(
    rate: float, dt: float, B: int, taps: np.ndarray, fs_in: float, tol: float, least: int
) -> int | None:
    """The highest integer order (at least ``least``) whose frequency at the fastest shaft
    rate ``rate`` (rev/s) the block and the filter together keep within ``tol`` of unit gain
    (the gain departs further above the passband)."""
    if not (math.isfinite(rate) and rate > 0):
        return None

    def ok(m: int) -> bool:
        f = m * rate
        g = (1.0 - attenuation(f, dt, B)) * float(_gain(taps, np.array([f]), fs_in)[0])
        return abs(g - 1.0) <= tol

    m = int(least)
    while ok(m + 1):
        m += 1
    return m


def decimate_recording(rec: Recording, info: dict, settings: FinderSettings) -> Recording:
    """Stage 2 on the stage-1 record ``rec`` (block means, ``info``: its ``reduced`` entry):
    ``info["decimation"]`` states it (``applied``, the factor, the filter, the rows; or the
    reason it is not applied); where applied, ``info`` gains the combined ``orders_kept``,
    ``reduced_rows`` and the lines the record can no longer test, and the decimated record is
    returned (else ``rec``)."""
    B, dt, tol = int(info["block_rows"]), float(info["dt_s"]), float(info["attenuation_max"])
    f_need = float(info["f_needed_hz"])
    fs_in = 1.0 / (B * dt)
    R = decimation_factor(fs_in, f_need, settings)
    dec: dict = {"applied": False, "factor": int(R), "rows_in": int(rec.n_rows)}
    info["decimation"] = dec
    if R <= 1:
        dec["reason"] = (
            f"the block means' rate {fs_in:.4g} Hz is under twice {RATE_OVER_NEEDED:g} x "
            f"f_needed_hz = {f_need:.4g} Hz"
            if settings.reduce_decimation_max > 1
            else "FinderSettings.reduce_decimation_max < 2 (stage 2 off)"
        )
        return rec
    got = design(fs_in, dt, B, f_need, R, tol)
    taps = got.pop("taps")
    if taps is None:
        dec["reason"] = f"no filter of up to {TAPS_MAX} taps keeps the bound"
        return rec
    n, h = rec.n_rows, (taps.size - 1) // 2
    angles = [*rec.head_columns, *(["theta_ref"] if "theta_ref" in rec.columns else [])]
    starts = stretch_starts(rec.columns, angles, shaft_of(rec.columns, rec.head_columns), B * dt)
    stretch = np.cumsum(starts) - 1
    centre = np.arange(h, n - h, R)  # the fixed grid of output centres
    centre = centre[stretch[centre - h] == stretch[centre + h]]  # whole window in a stretch
    if centre.size < MIN_ROWS_OUT:
        dec.update(
            reason=f"{centre.size} rows would be left (under {MIN_ROWS_OUT}): the stretches "
            f"of the block means are too short or too few for the filter ({taps.size} taps)",
            n_taps=int(taps.size),
        )
        return rec
    ints = set(SPECS[rec.kind].int_columns) | {"t"}
    fir = [k for k in rec.columns if k not in ints]
    got_fir = _filtered_columns([rec.columns[k] for k in fir], taps, centre)
    cols = {
        k: np.ascontiguousarray(got_fir[:, fir.index(k)])
        if k in fir
        else np.asarray(v)[centre].copy()
        for k, v in rec.columns.items()
    }
    stretches = int(np.count_nonzero(starts))
    dec.update(
        applied=True,
        **got,
        window=f"kaiser (beta {KAISER_BETA:g})",
        design="scipy.signal.firwin2: root-raised-cosine (square-root Nyquist) amplitude, "
        "symmetric (linear phase; an output at its centre tap's row and time)",
        rows_out=int(centre.size),
        rows_left_out=int(n - centre.size * R),
        stretches=stretches,
    )
    rate = float(info.get("shaft_rate_max_rev_s", math.nan))
    kept = combined_orders_kept(rate, dt, B, taps, fs_in, tol, int(info["orders_needed"]))
    info.update(
        orders_kept=kept,
        reduced_rows=int(centre.size),
        bound="the mean of B rows sampled every dt multiplies a sinusoid of frequency f by "
        "D = sin(pi f B dt) / (B sin(pi f dt)); the FIR of decimation (stage 2, symmetric: "
        "its phase at the centre tap's time) multiplies it by |H(f)|; at every frequency up "
        "to f_needed_hz (orders_needed x shaft_rate_max_rev_s, and line_band_hz) the "
        "combined gain D |H| is within attenuation_max (FinderSettings."
        "reduce_attenuation_max) of 1 (block_attenuation_max for the block, the rest for "
        "the filter), and so at every order up to orders_kept; a base grown so that the "
        "views would scan past orders_kept restarts the diagnosis on the reduction planned "
        "for every order the base can grow to (restart)",
    )
    lost = [
        {
            "name": "lines_above_band",
            "reason": f"the record is low-passed to {f_need:.4g} Hz and decimated to "
            f"{got['rate_out_hz']:.4g} Hz: lines above {f_need:.4g} Hz are attenuated, those "
            f"between {0.5 * got['rate_out_hz']:.4g} and {got['stopband_hz']:.4g} Hz folded "
            f"into the band, those above {got['stopband_hz']:.4g} Hz removed",
            "rule": "reduce_decimation_max",
        }
    ]
    info["not_testable"] = [*(info.get("not_testable") or []), *lost]
    meta = dict(rec.meta)
    meta[NOISE_BAND_KEY] = (f_need, float(got["rate_out_hz"]))  # (_prepare: its noise)
    return Recording(rec.kind, meta, cols, path=rec.path)


def chunk_share(n_out: int, parts: int, part: int) -> tuple[int, int]:
    """Outputs ``[lo, hi)`` of ``n_out`` that process ``part`` of ``parts`` filters: a
    contiguous share of the :data:`OUT_CHUNK` chunks (:func:`split_range`), so every chunk,
    and its ``w @ taps``, has the same rows and shape as on one process."""
    n_chunks = -(-int(n_out) // OUT_CHUNK)
    lo, hi = split_range(n_chunks, parts, part)
    return min(lo * OUT_CHUNK, n_out), min(hi * OUT_CHUNK, n_out)


def _filtered_columns(vs: list, taps: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``(centre.size, len(vs))``: the FIR ``taps`` on each column of ``vs`` at rows
    ``centre`` (:func:`_filtered`). On several processes (outside :func:`._rowshare.alone`)
    each filters its :func:`chunk_share` of the outputs and the shares are gathered (one
    :func:`allgather_concat`): every process ends with the same columns, bit for bit those
    of one process."""
    parts, part = (1, 0) if is_alone() else (jax.process_count(), jax.process_index())
    lo, hi = chunk_share(centre.size, parts, part)
    mine = np.empty((hi - lo, len(vs)))
    for j, v in enumerate(vs):
        mine[:, j] = _filtered(v, taps, centre[lo:hi])
    if parts == 1:
        return mine
    counts = [b - a for a, b in (chunk_share(centre.size, parts, p) for p in range(parts))]
    return allgather_concat(mine, counts)


def _filtered(v: np.ndarray, taps: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The FIR ``taps`` (odd, symmetric) on column ``v`` at rows ``centre``: each output the
    centre row's value plus the taps on the window's departures from it (few digits lost
    on a column far from zero, such as an unwrapped angle), :data:`OUT_CHUNK` at a time."""
    v = np.asarray(v, float)
    h = (taps.size - 1) // 2
    off = np.arange(-h, h + 1)
    out = np.empty(centre.size)
    for a in range(0, centre.size, OUT_CHUNK):
        c = centre[a : a + OUT_CHUNK]
        mid = v[c]
        w = v[c[:, None] + off[None, :]]
        w -= mid[:, None]
        out[a : a + c.size] = mid + w @ taps
    return out
