"""The discrepancy finder's engine: every stage written once, for every recording kind.

Stages (``docs/diagnose.md``):

1. **prepare** (:func:`prepare`): the kind turns the recording into observations ``y`` (n, C)
   and row columns; the engine finds the bench's nuisances: gaps in ``t``, segments where the
   shaft does not turn steadily (start-up, return moves, reversals, dwells, speed far from the
   segment's steady speed), single-sample glitches and count jumps; it estimates the noise per
   channel from second differences (structure smooth on the sampling scale cannot inflate it)
   and lays out K blocked, randomly assigned held-out folds.
2. **base fit**: the kind's base terms (one constant per channel and run, run angle offsets,
   the kind's error function up to the orders the record resolves) by Gauss-Newton /
   Levenberg-Marquardt on sufficient statistics accumulated chunk by chunk (bounded memory).
3. **locate** (:mod:`encdesign.diagnose._views`): views of the residual, each finding with
   where it sits and a p-value.
4. **select**: forward selection of candidates whose signature matches a finding, each refit
   with everything accepted so far; accepted on information criterion, K-fold held-out gain,
   plausibility and conditioning; then a backward check on held-out data.
5. **held-out proof**: the K-fold held-out residual of each model, from the per-fold
   sufficient statistics (exact for parameters the model is linear in).
6. **verdict** and report: ``consistent`` only when the goodness-of-fit test (variance ratio
   of the residual to the difference-based noise, globally and per time block) passes and no
   view finds anything.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable, MutableMapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
import scipy.signal
from scipy import stats

from .._errors import input_error
from ._candidates import Candidate, Context, Param
from ._views import ALPHA, SCAN_BLOCK, locate, order_sums, run_spans

VERDICTS = ("consistent", "missing_physics", "unexplained")
MAX_PARAM_FRACTION = 0.1
"""The model never has more parameters than this fraction of the fitted values."""
N_FOLDS = 5
BIC_MIN = 10.0
HELDOUT_MIN = 10.0
PLAUSIBLE_RATIO = 4.0
LOCATED_SHARE_MIN = 0.2
SIGNATURE_LEFT_MAX = 0.5
COLLINEAR_REFUSE = 0.995
COLLINEAR_NOTE = 0.95
# two candidates the data cannot tell apart: chi-square within TIE_CHI2 of each other and
# fitted errors correlated above TIE_CORR (over the kept rows, noise-whitened)
TIE_CHI2 = 10.0
TIE_CORR = 0.9
LATTICE_NOISE_SHARE = 0.25
"""``quantization`` is named from the readings' value lattice (a floor, not a fitted term)
when its floor ``LSB^2 / 12`` is at least this share of the channel's measured noise
variance: the LSB is then coarser than about twice the noise ahead of the quantizer, and the
reading's resolution, not the sensor's noise, sets the floor."""
CHUNK_ROWS = 8192
CACHE_BYTES = 6.0e7
"""Budget of each of the fitter's two caches (Jacobians of linear terms, processed static
blocks): what does not fit is recomputed, so memory stays bounded on long records."""
D2_VAR = 2.0 * (70.0 / 36.0 - 1.0)
"""Variance of log(residual variance / second-difference variance) times N (white noise)."""
MEDIAN_VAR = 2.0 / math.log(2.0) ** 2
"""Variance of log(median periodogram level) times the number of periodogram bins."""


# ----------------------------------------------------------------------------- kind data


@dataclasses.dataclass
class KindData:
    """What a kind hands the engine (numpy, SI). Built by the kind's ``data(rec)``.

    Attributes:
        y: observations ``(n, C)`` whose model is the sum of the terms (e.g. reading -
            theta_ref), in ``unit``.
        shaft: shaft angle per row (rad), used to find non-steady motion and revolutions.
        t: time within the run, s. run: run id per row (any ints).
        reading: each channel's reading ``(n, C)`` (rad) for line-phase terms; ``None``:
            read per chunk from ``reading_cols`` (the recording's own columns, one per
            channel: no copy per row).
        theta_ref: reference angle or ``None``. temp: ``temp_c`` or ``None``.
        alpha: channel azimuths (rad). radius_m: optical radius or ``None``.
        signal_periods: signal periods per revolution (0: unknown).
        project: remove the per-sample channel mean (no reference angle: only channel
            differences are observable).
        unit: unit of ``y``. channel_names: e.g. ``h0``...
        sensor: ``[encoder] sensor``.
        where: file name for messages.
        steady_tolerance: relative speed deviation beyond which a sample is non-steady.
        speed_window: the speed is measured over this fraction of the run (at least 5 rows;
            longer for a motor whose own ripple is large).
        segments: optional steady-segment id per row (>= 0), given by the kind instead of
            being found from the shaft motion (e.g. a quadrature capture sorted by phase
            has no motion to segment); ``None``: found by :func:`find_motion_segments`.
        masked: optional ``(mask (n,) bool, reason)`` pairs: rows the kind knows to leave out
            of every fit (e.g. clipped signals); each is reported as one excluded segment
            (first to last masked row) with its reason and the number of stretches.
    """

    y: np.ndarray
    shaft: np.ndarray
    t: np.ndarray
    run: np.ndarray
    reading: np.ndarray | None
    theta_ref: np.ndarray | None
    temp: np.ndarray | None
    alpha: np.ndarray
    radius_m: float | None
    signal_periods: int
    project: bool
    unit: str
    channel_names: list[str]
    sensor: str
    where: str
    steady_tolerance: float = 0.1
    speed_window: float = 0.01
    segments: np.ndarray | None = None
    masked: tuple[tuple[np.ndarray, str], ...] = ()
    reading_cols: tuple[np.ndarray, ...] = ()

    def __post_init__(self):
        if self.reading is None and len(self.reading_cols) != self.y.shape[1]:
            raise ValueError("KindData: reading is None and reading_cols is not one per channel")


@dataclasses.dataclass(frozen=True)
class Kind:
    """A recording kind: how to read it, its base model, its views and its candidates.

    Attributes:
        name: kind name.
        data: ``data(rec) -> KindData``.
        base: ``base(prep, max_order) -> ([(Candidate, start), ...], info)``: base-model
            terms for this record (``info``: ``{"unidentifiable": [...], "align": fn}``).
        candidates: ``candidates(ctx) -> tuple[Candidate, ...]``.
        views: names of the views run on the residual (or the kind's own view functions,
            ``view(prep, whitened_residual, scan_order) -> [Finding, ...]``).
        max_order_limit: ``limit(prep) -> int``: the highest order this record resolves.
        default_max_order: the base model's order when the user gives none.
        summary: ``summary(prep, base_params) -> dict`` of kind-specific keys for the JSON.
        prepare: ``prepare(kind_data, meta) -> Prepared`` replacing :func:`prepare` for a
            kind whose rows are not a time series of a turning shaft (``sds``: one row per
            platform position); ``None``: the engine's.
        noise: optional ``noise(prep, base_resid) -> (C,)``: a second noise estimate that the
            kind's own structure cannot inflate (e.g. differences of neighbours in signal
            phase for a quadrature capture in time order); the engine takes, per channel,
            the smaller of it and the periodogram median.
        noise_replaces: ``True``: the kind's ``noise`` replaces the periodogram median
            (``sds``: levels by degrees of freedom, rows are platform positions, not time).
        grows_orders: ``True``: integer orders above ``default_max_order`` that the base
            residual shows (up to what the record resolves) join the base model (a disk's
            error function has every order; :func:`_grow_base_order`).
        reading_lattice: ``True``: the channels are angle readings; one on a value lattice
            whose floor is a material part of its noise names ``quantization`` from the
            lattice (:func:`lattice_effect`).
    """

    name: str
    data: Callable[[Any], KindData]
    base: Callable[[Any, int], tuple[list, dict]]
    candidates: Callable[[Context], tuple[Candidate, ...]]
    views: tuple[str | Callable[..., Any], ...]
    max_order_limit: Callable[[Any], int]
    default_max_order: int = 12
    summary: Callable[[Any, dict], dict] | None = None
    prepare: Callable[[KindData, dict], Any] | None = None
    noise: Callable[[Any, np.ndarray], np.ndarray] | None = None
    noise_replaces: bool = False
    grows_orders: bool = False
    reading_lattice: bool = False


# ----------------------------------------------------------------------------- prepared


class RowColumns(MutableMapping):
    """Row columns of a prepared record.

    Stored columns are arrays (often the recording's own, not copies). ``run_onehot`` (n, R)
    is made on access from the run index; *lazy* columns are functions ``fn(lo, hi)`` of a row
    range, computed on access (whole column) or per chunk by :meth:`column`, so that a
    column that follows from others (time across runs, the segment speed, a signal phase)
    costs no memory per row. Assigning an array stores it; :meth:`set_lazy` assigns a
    function."""

    def __init__(
        self,
        cols: dict[str, np.ndarray],
        run: np.ndarray,
        n_runs: int,
        lazy: dict[str, Callable[[int, int | None], np.ndarray]] | None = None,
    ):
        self._d = dict(cols)
        self._lazy = dict(lazy or {})
        self.run = run
        self.n_runs = n_runs

    def onehot(self, lo: int = 0, hi: int | None = None) -> np.ndarray:
        """One-hot run membership of rows ``lo:hi``."""
        r = self.run[lo:hi]
        out = np.zeros((r.size, self.n_runs))
        out[np.arange(r.size), r] = 1.0
        return out

    def column(self, k: str, lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Rows ``lo:hi`` of column ``k`` (a lazy column computes only those rows)."""
        if k in self._d:
            return self._d[k][lo:hi]
        if k in self._lazy:
            return self._lazy[k](lo, hi)
        if k == "run_onehot":
            return self.onehot(lo, hi)
        raise KeyError(k)

    def take(self, k: str, idx) -> np.ndarray:
        """Column ``k`` at row indices ``idx`` (an int or an array): a lazy column is
        computed over the span of those rows only."""
        idx = np.asarray(idx)
        if idx.size == 0:
            return self.column(k, 0, 0)
        lo, hi = int(idx.min()), int(idx.max()) + 1
        return self.column(k, lo, hi)[idx - lo]

    def set_lazy(self, k: str, fn: Callable[[int, int | None], np.ndarray]) -> None:
        """Make ``k`` a lazy column ``fn(lo, hi)``."""
        self._d.pop(k, None)
        self._lazy[k] = fn

    def __getitem__(self, k: str) -> np.ndarray:
        return self.column(k)

    def __setitem__(self, k: str, v: np.ndarray) -> None:
        self._lazy.pop(k, None)
        self._d[k] = v

    def __delitem__(self, k: str) -> None:
        if k in self._d:
            del self._d[k]
        else:
            del self._lazy[k]

    def __contains__(self, k: object) -> bool:
        return k in self._d or k in self._lazy or k == "run_onehot"

    def __iter__(self):
        yield from self._d
        yield from (k for k in self._lazy if k not in self._d)
        if "run_onehot" not in self._d and "run_onehot" not in self._lazy:
            yield "run_onehot"

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def stored(self):
        """The stored columns (without the derived one-hot and the lazy columns)."""
        return self._d.items()

    def names(self) -> list[str]:
        """Every column a term can read, ``run_onehot`` last."""
        return [k for k in self if k != "run_onehot"] + ["run_onehot"]


class KeptRows(MutableMapping):
    """The row columns over the kept samples, selected on access (no stored copy; the
    columns themselves when every row is kept). Assigned columns are stored as given."""

    def __init__(self, rows: RowColumns, keep: np.ndarray):
        self._rows = rows
        self._keep = keep
        self._all = bool(keep.all())
        self._own: dict[str, np.ndarray] = {}

    def __getitem__(self, k: str) -> np.ndarray:
        if k in self._own:
            return self._own[k]
        v = self._rows[k]
        return v if self._all else v[self._keep]

    def __setitem__(self, k: str, v: np.ndarray) -> None:
        self._own[k] = v

    def __delitem__(self, k: str) -> None:
        del self._own[k]

    def __iter__(self):
        yield from self._rows
        yield from (k for k in self._own if k not in self._rows)

    def __len__(self) -> int:
        return len(set(self._rows) | set(self._own))


@dataclasses.dataclass
class Prepared:
    """A recording ready to fit: kept rows, row columns, noise, folds, nuisances."""

    kd: KindData
    ctx: Context
    y: np.ndarray  # (n, C), rows sorted run-by-run in file order
    rows: RowColumns  # row columns for the terms
    consts: dict[str, Any]
    keep: np.ndarray  # bool (n,)
    fold: np.ndarray  # int (n,), -1 for excluded rows
    seg: np.ndarray  # int (n,) steady segment id, -1 excluded
    sigma: np.ndarray  # (C,) noise std per channel
    excluded: list[dict]
    glitches: list[dict]
    count_jumps: list[dict]
    gaps: list[dict]
    fold_design: dict
    run_ids: np.ndarray
    run: np.ndarray  # run index 0..R-1

    @property
    def n(self) -> int:
        """Rows."""
        return self.y.shape[0]

    @property
    def n_channels(self) -> int:
        """Channels."""
        return self.y.shape[1]

    @property
    def n_values(self) -> float:
        """Independent fitted values (kept rows x channels, less the projection)."""
        C = self.n_channels
        return float(self.keep.sum() * (C - 1 if self.kd.project else C))


def _smooth_speed(shaft: np.ndarray, t: np.ndarray, win: int) -> np.ndarray:
    """Speed (rad/s): the least-squares slope of the angle over ``win`` rows centred on each
    row, as ``sum_k k theta_(i+k) / sum_k k t_(i+k)`` (k = -h..h; exact for a steady turn on
    any time grid, and it averages a quantized angle's rounding over the whole window rather
    than reading it at two ends). The run's ends are padded with their first / last row, which
    keeps the ratio exact there too."""
    n = shaft.size
    if n < 3:
        return np.zeros(n)
    h = max(1, win // 2)
    k = np.arange(h, -h - 1, -1, dtype=float)  # reversed: convolution is a correlation
    # subtract the mean line first (precision on long records)
    w0 = (shaft[-1] - shaft[0]) / (t[-1] - t[0]) if t[-1] != t[0] else 0.0
    tc = t - t[0]
    y = shaft - shaft[0] - w0 * tc
    yp = np.concatenate([np.full(h, y[0]), y, np.full(h, y[-1])])
    tp = np.concatenate([np.full(h, tc[0]), tc, np.full(h, tc[-1])])
    num = scipy.signal.oaconvolve(yp, k, mode="valid")
    den = scipy.signal.oaconvolve(tp, k, mode="valid")
    out = np.zeros(n)
    ok = den > 0
    out[ok] = num[ok] / den[ok] + w0
    return out


def _runs_of(mask: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous ``True`` stretches as (start, stop) index pairs."""
    if mask.size == 0:
        return []
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def speed_window_rows(
    shaft: np.ndarray, t: np.ndarray, tolerance: float = 0.1, window: float = 0.01
) -> int:
    """Rows over which the speed is measured when judging steadiness.

    At least ``window`` of the run (and 5 rows), and long enough that the shaft angle's own
    sample-to-sample scatter cannot move the speed estimate out of the ``tolerance``: the
    window slope (:func:`_smooth_speed`, ``w = 2 h + 1`` rows) of an angle with per-sample
    scatter ``s`` (rad) has a speed error ``s / (dt sqrt(S))``, ``S = h (h + 1) (2 h + 1) / 3``,
    held to ``tolerance / 3`` of the typical speed. The scatter is read from second
    differences (``s^2 = mean(d2^2) / 6`` over the smallest 95 %, so a reversal or a glitch
    does not count): a reference quantized to a step ``q`` scatters by about ``q / sqrt(12)``
    plus any sampling jitter, so a coarse reference gets a wider window instead of being read
    as unsteady. Capped at a quarter of the run (and 2001 rows).
    """
    n = shaft.size
    win = max(5, int(window * n))
    if n >= 16:
        a2 = np.sort(np.abs(np.diff(shaft, 2)))
        # mean square of the smallest 95 % (a reversal or a glitch does not count; a MAD
        # would read 0 on a quantized ramp whose second differences are mostly 0 and +-q)
        s = math.sqrt(float(np.mean(a2[: max(1, int(0.95 * a2.size))] ** 2)) / 6.0)
        dt = np.diff(t)
        dt_med = float(np.median(dt)) if dt.size else 0.0
        step = float(np.median(np.abs(np.diff(shaft))))  # typical angle advance per row
        if s > 0 and step > 0 and dt_med > 0:
            need_s = (3.0 * s / (tolerance * step)) ** 2  # S = sum k^2 needed
            h = 1
            while h * (h + 1) * (2 * h + 1) / 3.0 < need_s and h < n:
                h += 1
            win = max(win, 2 * h + 1)
        win = min(win, max(5, n // 4))
    return int(min(win, 2001))


def find_motion_segments(
    shaft: np.ndarray, t: np.ndarray, tolerance: float = 0.1, window: float = 0.01
) -> tuple[np.ndarray, list[dict]]:
    """Steady segments of one run.

    A sample is steady when the shaft turns in the direction of a long piece of the run at a
    speed within ``tolerance`` (relative) of that piece's median speed. Pieces are maximal
    stretches of one direction; a piece shorter than 10 % of the run (or 50 samples) is a
    return move, a reversal or a start-up, and samples slower than 10 % of the steady speed
    are dwells. Each excluded stretch is widened by the speed window (settling).

    Returns:
        ``(segment id per sample (-1 excluded), [excluded stretches {start, stop, reason}])``.
    """
    n = shaft.size
    win = speed_window_rows(shaft, t, tolerance, window)
    w = _smooth_speed(shaft, t, win)
    seg = -np.ones(n, dtype=int)
    out: list[dict] = []
    if n < 8:
        return np.zeros(n, dtype=int), out
    sgn = np.sign(w)
    big = np.abs(w) > 0.1 * np.median(np.abs(w))
    longest = max((b - a for a, b in _runs_of(big & (sgn > 0))), default=0)
    longest = max(longest, max((b - a for a, b in _runs_of(big & (sgn < 0))), default=0))
    min_len = max(50, int(0.1 * n), int(0.5 * longest) if longest < 0.2 * n else 0)
    min_len = min(min_len, max(50, int(0.1 * n)))
    sid = 0
    for s in (1, -1):
        for a, b in _runs_of(big & (sgn == s)):
            if b - a < min_len:
                continue
            med = np.median(w[a:b])
            ok = np.abs(w[a:b] - med) <= tolerance * abs(med)
            # a piece starts and ends where the speed first / last comes within 10 % of its
            # steady speed (a ramp is not steady even where it is inside a loose tolerance)
            near = np.flatnonzero(np.abs(w[a:b] - med) <= 0.1 * abs(med))
            # (a stretch shorter than the speed window is not resolved as a ramp: at a run's
            # end the window is one-sided and the estimate there leans on the last rows)
            if near.size:
                if near[0] >= win // 2 or a > 0:
                    ok[: near[0]] = False
                if (b - a) - 1 - near[-1] >= win // 2 or b < n:
                    ok[near[-1] + 1 :] = False
            for c, d in _runs_of(ok):
                if d - c >= min(min_len, 20):
                    seg[a + c : a + d] = sid
                    sid += 1
    # widen the exclusions (settling after a move)
    bad = seg < 0
    if bad.any() and not bad.all():
        widened = bad.copy()
        h = max(win, n // 50)
        for a, b in _runs_of(bad):
            widened[max(0, a - h) : min(n, b + h)] = True
        seg[widened & ~bad] = -1
    for a, b in _runs_of(seg < 0):
        piece = w[a:b]
        steady = np.median(np.abs(w[seg >= 0])) if (seg >= 0).any() else 0.0
        if np.median(np.abs(piece)) < 0.1 * steady:
            reason = "dwell (shaft nearly at rest)"
        elif (
            (seg[:a] >= 0).any()
            and (seg[b:] >= 0).any()
            and np.any(np.sign(piece) != np.sign(np.median(w[seg >= 0])))
        ):
            reason = "reversal or return move (direction changes)"
        elif a == 0:
            reason = "start-up (speed far from the steady speed)"
        elif np.any(np.sign(piece) != np.sign(np.median(w[seg >= 0]) if steady else 1)):
            reason = "return move (opposite direction)"
        else:
            reason = "speed far from the segment's steady speed"
        out.append(dict(start=a, stop=b, reason=reason))
    return seg, out


def _noise_d2(r: np.ndarray, seg: np.ndarray, t: np.ndarray | None = None):
    """Second differences of ``r`` (n, C) within segments, on any time grid: each value less
    the straight line through its two neighbours, scaled so that white noise of std sigma
    gives ``6 sigma^2`` (as the plain second difference on a uniform grid). A straight line
    gives exactly zero on any grid. Returns (values (m, C), index of the centre row).

    Computed in blocks of :data:`SCAN_BLOCK` rows (temporaries bounded by the block)."""
    n, C = r.shape
    if n < 3:
        return np.zeros((0, C)), np.zeros(0, dtype=np.int64)
    ok = (seg[2:] == seg[1:-1]) & (seg[1:-1] == seg[:-2]) & (seg[1:-1] >= 0)
    centre = np.flatnonzero(ok) + 1
    out = np.empty((centre.size, C))
    pos = 0
    for a in range(1, n - 1, SCAN_BLOCK):
        b = min(n - 1, a + SCAN_BLOCK)  # centres a..b-1
        okb = ok[a - 1 : b - 1]
        m = int(okb.sum())
        if m == 0:
            continue
        rm, r0, rp = r[a - 1 : b - 1], r[a:b], r[a + 1 : b + 1]
        if t is None:
            d2 = rp - 2 * r0 + rm
        else:
            h1 = t[a:b] - t[a - 1 : b - 1]
            h2 = t[a + 1 : b + 1] - t[a:b]
            hs = np.where(h1 + h2 > 0, h1 + h2, 1.0)
            w1, w2 = h2 / hs, h1 / hs
            e = r0 - (w1[:, None] * rm + w2[:, None] * rp)
            d2 = -2.0 * e * np.sqrt(1.5 / (1.0 + w1**2 + w2**2))[:, None]
        out[pos : pos + m] = d2[okb]
        pos += m
    return out, centre


TRIM_QUANTILE = 0.99
"""Share of the smallest ``|d2|`` kept by the trimmed-RMS scale of :func:`robust_scale`."""
_TRIM_RMS = math.sqrt(
    1.0
    - 2.0
    * stats.norm.isf((1 - TRIM_QUANTILE) / 2)
    * stats.norm.pdf(stats.norm.isf((1 - TRIM_QUANTILE) / 2))
    / TRIM_QUANTILE
)
"""RMS of a unit Gaussian within its central ``TRIM_QUANTILE`` (0.962 at 99 %)."""


ROBUST_ROWS = 1 << 18
"""Rows :func:`robust_scale` reads at most."""


def robust_scale(d: np.ndarray) -> np.ndarray:
    """Robust std per column of ``d`` (m, C), centred at zero: the larger of 1.4826 MAD and
    the RMS of the central ``TRIM_QUANTILE`` of ``|d|`` (scaled to a Gaussian's std).

    The MAD alone collapses on values that sit on a lattice: the second differences of a
    quantized reading are mostly exactly 0 (then +-1 LSB), so their MAD is 0 and every step
    of the staircase would read as a glitch or a count jump. The trimmed RMS sees the
    lattice's spread, and a few glitches (under 1 % of the values) cannot inflate it; for
    Gaussian noise both read sigma. Over ``ROBUST_ROWS`` rows, from that many rows drawn at
    random (fixed seed: the scale to a few parts per thousand, memory bounded)."""
    if d.shape[0] > ROBUST_ROWS:
        d = d[np.sort(np.random.default_rng(0).integers(0, d.shape[0], ROBUST_ROWS))]
    a = np.abs(d)
    mad = 1.4826 * np.median(a, axis=0)
    if a.shape[0] < 8:
        return mad
    cut = np.quantile(a, TRIM_QUANTILE, axis=0)
    inner = np.where(a <= cut[None, :], a, 0.0)
    cnt = np.maximum(np.sum(a <= cut[None, :], axis=0), 1)
    trim = np.sqrt(np.einsum("ij,ij->j", inner, inner) / cnt) / _TRIM_RMS
    return np.maximum(mad, trim)


def noise_sigma(
    r: np.ndarray, seg: np.ndarray, robust: bool = False, t: np.ndarray | None = None
) -> np.ndarray:
    """Noise std per channel from second differences within segments:
    ``var(d2) = 6 sigma^2`` for white noise; structure smooth on the sampling scale adds
    ``(omega dt)^4`` of its variance only. ``robust``: from the MAD (glitch-proof)."""
    d2, _ = _noise_d2(r, seg, t)
    if d2.shape[0] < 4:
        return np.full(r.shape[1], np.nan)
    if robust:
        med = np.median(d2, 0)
        d2 -= med[None, :]
        return robust_scale(d2) / math.sqrt(6.0)
    return np.sqrt(np.einsum("ij,ij->j", d2, d2) / d2.shape[0] / 6.0)


def noise_spectral(prep: Prepared, resid: np.ndarray) -> np.ndarray:
    """Noise std per channel from the median of the residual's periodogram, run by run.

    For white noise each periodogram bin ``|X_j|^2 / n`` is ``sigma^2`` times a unit
    exponential, whose median is ``ln 2``; structure in fewer than half of the bins (lines,
    a band, a slow drift, a step) cannot inflate the median much, at any frequency (second
    differences are inflated by structure near the Nyquist frequency)."""
    C = resid.shape[1]
    bins = [[] for _ in range(C)]
    for r in range(prep.ctx.n_runs):
        rows = np.flatnonzero(prep.run == r)
        kr = prep.keep[rows]
        nk = int(kr.sum())
        if nk < 16:
            continue
        x = np.where(kr[:, None], resid[rows], 0.0)
        x = x - np.where(kr[:, None], x.sum(0) / nk, 0.0)
        P = np.abs(np.fft.rfft(x, axis=0)) ** 2 / nk
        P = P[1 : (x.shape[0] - 1) // 2 + 1]
        for k in range(C):
            bins[k].append(P[:, k])
    out = np.full(C, np.nan)
    eff = (C - 1) / C if prep.kd.project and C > 1 else 1.0
    for k in range(C):
        if bins[k]:
            allb = np.concatenate(bins[k])
            if allb.size >= 8:
                out[k] = math.sqrt(np.median(allb) / math.log(2.0) / eff)
    return out


def find_glitches(
    r: np.ndarray, seg: np.ndarray, project: bool, t: np.ndarray | None = None
) -> tuple[list[tuple[int, int]], list[tuple[int, int, float]]]:
    """Single-sample glitches and count jumps in ``r`` (n, C).

    On the second differences (any grid, :func:`_noise_d2`), a glitch of size g at row i
    gives ``(-1, 2, -1) g`` at rows ``i-1, i, i+1``; a step between rows i-1 and i gives
    ``(s, -s)`` at ``i-1, i``. Outliers beyond the Gaussian quantile at ``1e-4 / n`` (MAD
    scale) are classified by that pattern; a clean record has none.

    Returns:
        ``([(row, channel)] glitches, [(row of the first new value, channel, size)] jumps)``;
        channel -1 when the projection cannot tell which channel (two channels, no reference).
    """
    n, C = r.shape
    d2, centre = _noise_d2(r, seg, t)
    out_g: list[tuple[int, int]] = []
    out_j: list[tuple[int, int, float]] = []
    if d2.shape[0] < 8:
        return out_g, out_j
    s = robust_scale(d2)  # not the bare MAD: it collapses on a quantized reading
    s = np.where(s > 0, s, np.inf)
    thr = stats.norm.isf(1e-4 / max(n, 1) / 2)
    hit = np.zeros(d2.shape[0], bool)
    for a in range(0, d2.shape[0], SCAN_BLOCK):
        hit[a : a + SCAN_BLOCK] = np.any(np.abs(d2[a : a + SCAN_BLOCK]) > thr * s, 1)
    hit_idx = np.flatnonzero(hit)
    del hit
    # the centres near a hit (row -> index into d2), and their z values
    near = np.unique(np.concatenate([hit_idx + d for d in (-2, -1, 0, 1, 2)]))
    near = near[(near >= 0) & (near < d2.shape[0])]
    pos = {int(centre[i]): int(i) for i in near}
    z = {int(i): d2[i] / s for i in near}
    hit_rows = sorted({int(centre[i]) for i in hit_idx})
    done: set[int] = set()
    for row in hit_rows:
        if row in done:
            continue
        i = pos[row]
        k = int(np.argmax(np.abs(z[i])))
        # the strongest centre in the neighbourhood
        cands = [pos[q] for q in (row - 1, row, row + 1) if q in pos]
        i = max(cands, key=lambda j: abs(z[j][k]))
        row = int(centre[i])
        zi = z[i][k]
        zl = z[pos[row - 1]][k] if row - 1 in pos else 0.0
        zr = z[pos[row + 1]][k] if row + 1 in pos else 0.0
        kk = -1 if (project and C == 2) else k
        if (
            np.sign(zl) == -np.sign(zi)
            and np.sign(zr) == -np.sign(zi)
            and (0.25 < abs(zl / zi) < 0.75 and 0.25 < abs(zr / zi) < 0.75)
        ):
            out_g.append((row, kk))
            done |= {row - 1, row, row + 1}
            continue
        # step: the neighbour of opposite sign and similar size
        for nb, zn in ((row + 1, zr), (row - 1, zl)):
            if np.sign(zn) == -np.sign(zi) and 0.6 < abs(zn / zi) < 1.6:
                first = max(row, nb)
                size = float(-d2[i, k] / 2.0 * (1 if first == row + 1 else -1))
                # the step size: jump of the level between the two rows
                a, b = first - 1, first
                size = float(r[b, k] - r[a, k])
                out_j.append((first, kk, size))
                done |= {row - 1, row, row + 1, nb}
                break
        else:
            out_g.append((row, kk))
            done |= {row}
    return out_g, out_j


def _fold_blocks(prep_keep: np.ndarray, run: np.ndarray, k: int, seed: int = 0):
    """K folds of contiguous blocks of kept rows, blocks assigned at random (balanced) per run:
    random assignment cannot alias with any periodic structure."""
    fold = -np.ones(run.size, dtype=np.int8)
    rng = np.random.default_rng(seed)
    block_rows = []
    for r in np.unique(run):
        rows = np.flatnonzero((run == r) & prep_keep)
        if rows.size == 0:
            continue
        nb = max(k, min(64, rows.size // 16))
        nb = max(k, nb - nb % k)
        edges = np.linspace(0, rows.size, nb + 1).astype(int)
        assign = np.tile(np.arange(k), nb // k)
        rng.shuffle(assign)
        for b in range(nb):
            fold[rows[edges[b] : edges[b + 1]]] = assign[b]
        block_rows.append(int(np.median(np.diff(edges))))
    design = {
        "k": k,
        "scheme": "contiguous blocks of kept rows within each run, assigned to folds at random "
        "(balanced, seed 0); each fold is predicted by the model fitted on the other K-1",
        "block_rows_median": int(np.median(block_rows)) if block_rows else 0,
        "seed": seed,
    }
    return fold, design


def prepare(kd: KindData, meta: dict) -> Prepared:
    """Stage 1: nuisances, noise, folds (see module doc). Raises EncdesignInputError."""
    n, C = kd.y.shape
    where = kd.where
    if n < 32:
        raise input_error(where, f"only {n} rows", "at least 32 rows to diagnose")
    if not np.all(np.isfinite(kd.y)):
        raise input_error(where, "non-finite readings", "finite values")
    run_ids, first, inv = np.unique(kd.run, return_index=True, return_inverse=True)
    order_runs = run_ids[np.argsort(first)]
    # run index 0..R-1 in file order, 4 bytes a row
    rank = np.empty(run_ids.size, dtype=np.int32)
    rank[np.argsort(first)] = np.arange(run_ids.size, dtype=np.int32)
    run = rank[inv.reshape(-1)]
    del inv
    R = order_runs.size
    # rows sorted run by run in time (most records already are: then nothing is copied)
    in_order = bool(np.all(np.diff(run) >= 0)) and all(
        np.all(np.diff(kd.t[a:b]) >= 0) for _, (a, b) in run_spans(run)
    )
    sort = None if in_order else np.lexsort((kd.t, run))  # prepared row -> file row
    if sort is not None:
        kd = dataclasses.replace(
            kd,
            y=kd.y[sort],
            shaft=kd.shaft[sort],
            t=kd.t[sort],
            run=kd.run[sort],
            reading=(kd.reading if kd.reading is not None else np.stack(kd.reading_cols, 1))[sort],
            reading_cols=(),
            theta_ref=None if kd.theta_ref is None else kd.theta_ref[sort],
            temp=None if kd.temp is None else kd.temp[sort],
            segments=None if kd.segments is None else kd.segments[sort],
            masked=tuple((m[sort], why) for m, why in kd.masked),
        )
        run = run[sort]
    t = kd.t
    # gaps and segments
    seg = -np.ones(n, dtype=np.int32)
    excluded: list[dict] = []
    gaps: list[dict] = []
    nseg = 0
    revs = np.zeros(R)
    seg_speed: list[float] = []
    for r in range(R):
        rows = np.flatnonzero(run == r)
        tr = t[rows]
        dt = np.diff(tr)
        med = np.median(dt) if dt.size else 1.0
        cuts = np.flatnonzero(dt > 20.0 * med) + 1
        for c in cuts:
            gaps.append(
                dict(run=int(order_runs[r]), t_s=float(tr[c - 1]), duration_s=float(dt[c - 1]))
            )
        bounds = [0, *cuts.tolist(), rows.size]
        for a, b in zip(bounds[:-1], bounds[1:]):
            sub = rows[a:b]
            if sub.size < 8:
                excluded.append(
                    dict(
                        run=int(order_runs[r]),
                        t_start_s=float(t[sub[0]]),
                        t_end_s=float(t[sub[-1]]),
                        n_rows=int(sub.size),
                        reason="too few rows between gaps",
                    )
                )
                continue
            if kd.segments is not None:  # given by the kind (no motion to segment)
                s_id = np.asarray(kd.segments[sub], dtype=int)
                s_id = np.unique(s_id, return_inverse=True)[1].reshape(s_id.shape)
                bad = []
            else:
                s_id, bad = find_motion_segments(
                    kd.shaft[sub], t[sub], kd.steady_tolerance, kd.speed_window
                )
            for sid in np.unique(s_id[s_id >= 0]):
                m = sub[s_id == sid]
                seg[m] = nseg
                w = np.polyfit(t[m] - t[m].mean(), kd.shaft[m], 1)[0] if m.size > 2 else 0.0
                seg_speed.append(float(w))
                revs[r] += abs(kd.shaft[m[-1]] - kd.shaft[m[0]]) / (2 * np.pi)
                nseg += 1
            for e in bad:
                ss = sub[e["start"] : e["stop"]]
                excluded.append(
                    dict(
                        run=int(order_runs[r]),
                        t_start_s=float(t[ss[0]]),
                        t_end_s=float(t[ss[-1]]),
                        n_rows=int(ss.size),
                        reason=e["reason"],
                    )
                )
    # the steady segments of the motion (their speeds give omega and the direction)
    seg_motion = seg.copy() if kd.masked else seg
    for mask, why in kd.masked:  # rows the kind leaves out (e.g. clipped signals)
        mask = np.asarray(mask, bool) & (seg >= 0)
        if mask.any():
            idx = np.flatnonzero(mask)
            excluded.append(
                dict(
                    run=int(order_runs[run[idx[0]]]),
                    t_start_s=float(t[idx[0]]),
                    t_end_s=float(t[idx[-1]]),
                    n_rows=int(idx.size),
                    reason=why,
                    stretches=len(_runs_of(mask)),
                )
            )
            seg[mask] = -1
    keep = seg >= 0
    if keep.sum() < 32:
        raise input_error(
            where, "no steady segment of at least 32 rows", "a shaft turning steadily"
        )
    # noise (robust first), glitches and count jumps on a first detrended residual
    # kd.y is the kind's own array (never the user's columns) and is not modified: no copy
    y = kd.y - kd.y.mean(1, keepdims=True) if kd.project else kd.y
    if y is not kd.y:  # one (n, C) array held, not two
        kd = dataclasses.replace(kd, y=y)
    glitches_raw, jumps_raw = find_glitches(_detrend(y, seg), seg, kd.project, t)
    glitches, count_jumps = [], []
    for i, k in glitches_raw:
        keep[i] = False
        glitches.append(
            dict(
                run=int(order_runs[run[i]]),
                t_s=float(t[i]),
                row=int(i if sort is None else sort[i]),
                channel=None if k < 0 else kd.channel_names[k],
            )
        )
    for i, k, size in jumps_raw:
        count_jumps.append(
            dict(
                run=int(order_runs[run[i]]),
                t_s=float(t[i]),
                row=int(i if sort is None else sort[i]),
                channel=None if k < 0 else kd.channel_names[k],
                channel_index=k,
                size=size,
                index=i,
                note="a step of one channel's reading (missed or extra counts); modelled as "
                "a constant change from then on"
                + ("; two channels without a reference: which one cannot be told" if k < 0 else ""),
            )
        )
    seg_eff = seg if np.array_equal(keep, seg >= 0) else np.where(keep, seg, -1).astype(np.int32)
    seg_noise = seg_eff.copy() if jumps_raw else seg_eff
    for i, _, _ in jumps_raw:  # the step itself is not noise
        seg_noise[max(i - 1, 0) : i + 1] = -1
    yd = _detrend(y, seg_eff)
    sigma = noise_sigma(yd, seg_noise, robust=False, t=t)
    sigma_r = noise_sigma(yd, seg_noise, robust=True, t=t)
    del yd
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, sigma_r)
    if not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
        raise input_error(where, "the noise cannot be estimated", "readings that vary")
    fold, design = _fold_blocks(keep, run, N_FOLDS)
    fold[~keep] = -1
    # row columns: the recording's own arrays, or lazy (computed per chunk from them)
    t0_run = np.zeros(R)
    off_run = np.zeros(R)
    off = 0.0
    for r, (a, b) in run_spans(run):
        tr = t[a:b]
        dtm = float(np.median(np.diff(tr))) if b - a > 1 else 1.0
        t0_run[r] = tr[0]
        off_run[r] = off
        off = tr[-1] - tr[0] + off + dtm

    def tau_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Time across the runs, each run after the previous one (s)."""
        ru = run[lo:hi]
        return t[lo:hi] - t0_run[ru] + off_run[ru]

    speeds = np.asarray([*seg_speed, 0.0])  # index -1: no steady segment

    def omega_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Steady speed of the row's segment (rad/s; 0 outside segments)."""
        return speeds[seg_motion[lo:hi]]

    def direction_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        return np.where(omega_rows(lo, hi) >= 0, 1.0, -1.0)

    theta = kd.theta_ref if kd.theta_ref is not None else kd.shaft
    if kd.temp is not None and np.ptp(kd.temp[keep]) > 0:
        temp, t_mean = kd.temp, float(kd.temp[keep].mean())
        driver_name = "temp_c"

        def driver_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
            return temp[lo:hi] - t_mean
    else:
        tau_mean = float(np.mean(tau_rows()[keep]))
        driver_name = "time"

        def driver_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
            return tau_rows(lo, hi) - tau_mean

    L = kd.signal_periods

    def reading_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Each channel's reading (rad)."""
        if kd.reading is not None:
            return kd.reading[lo:hi]
        return np.stack([c[lo:hi] for c in kd.reading_cols], 1)

    def psi_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Signal phase of each channel's reading (rad); zero without signal periods."""
        if L > 0:
            return np.mod(L * reading_rows(lo, hi), 2 * np.pi)
        m = (hi if hi is not None else n) - lo
        return np.broadcast_to(0.0, (max(m, 0), C))

    stored = dict(
        t=t,
        theta=theta,
        # no reference: zero (a read-only broadcast, no memory)
        theta_ref=kd.theta_ref if kd.theta_ref is not None else np.broadcast_to(0.0, (n,)),
    )
    lazy = dict(
        tau=tau_rows,
        omega=omega_rows,
        direction=direction_rows,
        driver=driver_rows,
        psi=psi_rows,
        reading=reading_rows,
    )
    if kd.reading is not None:
        stored["reading"] = kd.reading
        del lazy["reading"]
    rows = RowColumns(stored, run, R, lazy)
    dt_med = float(np.median(np.diff(t))) if n > 1 else 1.0
    consts = dict(
        step_width_s=np.asarray(0.5 * abs(dt_med) if dt_med > 0 else 1e-3),
        alpha=np.asarray(kd.alpha, float),
        radius_m=np.asarray(kd.radius_m if kd.radius_m else 1.0, float),
        signal_periods=np.asarray(float(L)),
        n_runs=np.asarray(float(R)),
    )
    krows = KeptRows(rows, keep)
    ctx = Context(
        kind=meta.get("kind", ""),
        n_channels=C,
        n_runs=R,
        has_ref=kd.theta_ref is not None,
        sensor=kd.sensor,
        signal_periods=L,
        radius_m=kd.radius_m,
        rows=krows,
        consts=consts,
        noise=sigma,
        revolutions=revs,
        meta=meta,
    )
    ctx.consts["driver_name"] = driver_name  # type: ignore[index]
    return Prepared(
        kd=kd,
        ctx=ctx,
        y=y,
        rows=rows,
        consts=consts,
        keep=keep,
        fold=fold,
        seg=seg_eff,
        sigma=sigma,
        excluded=excluded,
        glitches=glitches,
        count_jumps=count_jumps,
        gaps=gaps,
        fold_design=design,
        run_ids=order_runs,
        run=run,
    )


def _detrend(y: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """``y`` less a per-segment quadratic in the row's rank within its segment, mapped to
    [-1, 1] (for the noise and glitch scans only). Normal equations accumulated in blocks:
    the temporaries are bounded by :data:`SCAN_BLOCK` rows, not by the segment."""
    out = np.zeros_like(y)
    ids = np.flatnonzero(seg >= 0)
    if ids.size == 0:
        return out
    order = ids[np.argsort(seg[ids], kind="stable")]  # rows grouped by segment, in order
    del ids
    sv = seg[order]
    cut = np.flatnonzero(np.diff(sv)) + 1
    edges = [0, *cut.tolist(), order.size]
    for lo, hi in zip(edges[:-1], edges[1:]):
        cnt = hi - lo
        den = max(cnt - 1, 1)

        def design(a: int, b: int, lo=lo, den=den, cnt=cnt) -> np.ndarray:
            x = (
                -1.0 + 2.0 * (np.arange(a - lo, b - lo, dtype=float) / den)
                if cnt > 1
                else np.full(b - a, -1.0)
            )
            return np.stack([np.ones_like(x), x, x**2], 1)

        G = np.zeros((3, 3))
        h = np.zeros((3, y.shape[1]))
        for a in range(lo, hi, SCAN_BLOCK):
            b = min(hi, a + SCAN_BLOCK)
            X = design(a, b)
            yb = y[order[a:b]]
            G += X.T @ X
            h += X.T @ yb
        coef = np.linalg.lstsq(G, h, rcond=None)[0]
        for a in range(lo, hi, SCAN_BLOCK):
            b = min(hi, a + SCAN_BLOCK)
            rows = order[a:b]
            out[rows] = y[rows] - design(a, b) @ coef
    return out


# ----------------------------------------------------------------------------- fitting


@functools.lru_cache(maxsize=256)
def _valjac_fn(cand: Candidate):
    # one jacfwd over all parameters (splitting it into linear and nonlinear tangents was
    # ~5x faster on the base term, but jax 0.10.2's CPU jit returned a Jacobian with zero
    # rows for the nonlinear half: checked against finite differences, not used)
    def vj(p, x):
        v = cand.fn(p, x)
        J = jax.jacfwd(cand.fn)(p, x)
        return v, J

    return jax.jit(vj)


@functools.lru_cache(maxsize=256)
def _val_fn(cand: Candidate):
    return jax.jit(cand.fn)


@dataclasses.dataclass
class Term:
    """A candidate with its current parameter values and which scalars are free."""

    cand: Candidate
    values: dict[str, np.ndarray]
    free: dict[str, np.ndarray]  # bool masks, same shapes
    scale: dict[str, np.ndarray]

    def flat(self) -> np.ndarray:
        """Values of the free scalars, in parameter order."""
        return np.concatenate(
            [self.values[p.name][self.free[p.name]].ravel() for p in self.cand.params]
            or [np.zeros(0)]
        )

    def n_free(self) -> int:
        """Free scalars."""
        return int(sum(int(self.free[p.name].sum()) for p in self.cand.params))

    def copy(self) -> Term:
        """A deep copy."""
        return Term(
            self.cand,
            {k: v.copy() for k, v in self.values.items()},
            {k: v.copy() for k, v in self.free.items()},
            {k: v.copy() for k, v in self.scale.items()},
        )


def make_term(cand: Candidate, prep: Prepared, start: dict | None = None) -> Term:
    """A :class:`Term` at ``start`` (others zero), free where the parameter is fitted."""
    C, R = prep.n_channels, prep.ctx.n_runs
    vals, free, scale = {}, {}, {}
    for p in cand.params:
        shp = p.resolved_shape(C, R)
        v = np.zeros(shp)
        if start and p.name in start:
            v = np.broadcast_to(np.asarray(start[p.name], float), shp).copy()
        vals[p.name] = v
        free[p.name] = np.full(shp, bool(p.fit))
        scale[p.name] = np.full(shp, p.scale if p.scale else 1.0)
    return Term(cand, vals, free, scale)


@dataclasses.dataclass
class FitResult:
    """Sufficient statistics of a fitted model and what follows from them."""

    terms: list[Term]
    chi2: float  # whitened residual sum of squares (kept rows)
    n_params: int
    cov: np.ndarray  # covariance of the free scalars (parameter units)
    heldout_chi2: float
    heldout_ssr: float  # unwhitened, for an RMS
    ssr: float
    n_rows: int
    converged: bool
    A: np.ndarray  # whitened normal matrix in parameter units (free scalars)
    unidentifiable: list[str]
    slices: list[tuple[int, int]]  # per term, range in the free vector
    determined: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, int))

    def n_determined(self, index: int) -> int:
        """Determined (fitted) scalars of term ``index``."""
        s0, s1 = self.slices[index]
        return int(np.sum((self.determined >= s0) & (self.determined < s1)))

    def rms(self, prep: Prepared) -> float:
        """Fitted residual RMS (unit of y)."""
        return math.sqrt(self.ssr / max(prep.n_values, 1))

    def heldout_rms(self, prep: Prepared) -> float:
        """K-fold held-out residual RMS (unit of y)."""
        return math.sqrt(self.heldout_ssr / max(prep.n_values, 1))


class Fitter:
    """Chunked evaluation of a sum of terms, its Jacobian and the per-fold statistics."""

    def __init__(self, prep: Prepared, progress: Callable[[int, int, int], None] | None = None):
        self.prep = prep
        self.w_ch = 1.0 / prep.sigma**2
        n = prep.n
        self.chunk = int(min(CHUNK_ROWS, 1 << max(5, int(math.ceil(math.log2(max(n, 2)))))))
        self.progress = progress
        self._jcache: dict = {}
        self._jbytes = 0
        self._pcache: dict = {}
        self._pbytes = 0
        self._gram: dict = {}

    def _chunks(self):
        prep = self.prep
        n = prep.n
        c = self.chunk
        for a in range(0, n, c):
            b = min(n, a + c)
            pad = c - (b - a)
            x = {}
            for k in prep.rows.names():
                s = prep.rows.column(k, a, b)
                if pad:
                    s = np.concatenate([s, np.repeat(s[-1:], pad, axis=0)], axis=0)
                x[k] = s
            x.update({k: v for k, v in prep.consts.items() if isinstance(v, np.ndarray)})
            yield a, b, x
            if self.progress is not None:
                self.progress(a, b, n)

    def clear(self) -> None:
        """Drop the cached Jacobians (after a row column changed)."""
        self._jcache.clear()
        self._pcache.clear()
        self._gram.clear()
        self._jbytes = self._pbytes = 0

    @staticmethod
    def _linear_only(term: Term) -> bool:
        return all(q.linear or not term.free[q.name].any() for q in term.cand.params)

    def _eval_term(self, term: Term, a: int, b: int, x: dict, jac: bool):
        """Value (rows, C) and Jacobian (rows, C, free) of one term on one chunk.

        A term whose free parameters are all linear is ``v0 + J p_lin`` with ``v0`` and ``J``
        depending only on the held (nonlinear) parameters: those are cached (within a
        memory budget), so refits with other terms cost one matrix product."""
        p = {k: jnp.asarray(v) for k, v in term.values.items()}
        if self._linear_only(term):
            held = tuple(term.values[q.name].tobytes() for q in term.cand.params if not q.linear)
            fmask = tuple(term.free[q.name].tobytes() for q in term.cand.params)
            key = (id(term.cand), a, held, fmask)
            hit = self._jcache.get(key)
            if hit is None:
                p0 = {
                    q.name: (jnp.zeros_like(p[q.name]) if q.linear else p[q.name])
                    for q in term.cand.params
                }
                v0, J = _valjac_fn(term.cand)(p0, x)
                v0 = np.asarray(v0)[: b - a]
                Jt = self._gather(term, J, b - a, v0.shape[1])
                hit = (v0, Jt)
                nbytes = Jt.nbytes + v0.nbytes
                if self._jbytes + nbytes < CACHE_BYTES:
                    self._jcache[key] = hit
                    self._jbytes += nbytes
            v0, Jt = hit
            lin = np.concatenate(
                [term.values[q.name][term.free[q.name]].ravel() for q in term.cand.params]
                or [np.zeros(0)]
            )
            # held linear parameters (fit=False) enter through v0 only when zero: add them
            v = v0 + Jt @ lin if lin.size else v0.copy()
            held_lin = [
                q
                for q in term.cand.params
                if q.linear
                and (~term.free[q.name]).any()
                and np.any(term.values[q.name][~term.free[q.name]] != 0)
            ]
            if held_lin:
                v = np.asarray(_val_fn(term.cand)(p, x))[: b - a]
            return v, Jt
        if jac:
            v, J = _valjac_fn(term.cand)(p, x)
            v = np.asarray(v)[: b - a]
            return v, self._gather(term, J, b - a, v.shape[1])
        v = np.asarray(_val_fn(term.cand)(p, x))[: b - a]
        return v, None

    @staticmethod
    def _gather(term: Term, J: dict, rows: int, C: int) -> np.ndarray:
        cols = []
        for par in term.cand.params:
            Jp = np.asarray(J[par.name])[:rows]
            Jp = Jp.reshape(rows, C, -1)
            cols.append(Jp[:, :, term.free[par.name].ravel()])
        return np.concatenate(cols, axis=2) if cols else np.zeros((rows, C, 0))

    def chunk_residual(self, terms: Sequence[Term], a: int, b: int, x: dict) -> np.ndarray:
        """Residual of rows ``a:b`` (projected when the kind says so), from the chunk's row
        columns ``x`` (as :meth:`_chunks` yields them)."""
        prep = self.prep
        pred = np.zeros((b - a, prep.n_channels))
        for tm in terms:
            pred += self._eval_term(tm, a, b, x, jac=False)[0]
        r = prep.y[a:b] - pred
        if prep.kd.project:
            r = r - r.mean(1, keepdims=True)
        return r

    def iter_residual(self, terms: Sequence[Term]):
        """``(a, b, residual of rows a:b)`` chunk by chunk: statistics of a residual without
        holding it whole."""
        for a, b, x in self._chunks():
            yield a, b, self.chunk_residual(terms, a, b, x)

    def residual(self, terms: Sequence[Term]) -> np.ndarray:
        """Residual ``(n, C)`` (projected when the kind says so), all rows."""
        out = np.empty_like(self.prep.y)
        for a, b, r in self.iter_residual(terms):
            out[a:b] = r
        return out

    def _processed(self, terms: Sequence[Term], a: int, b: int, x: dict, sc: np.ndarray):
        """Projected, scaled, whitened, fold-sorted Jacobian and prediction of ``terms`` on
        one chunk: ``(pred (rows, C), J (rows, C, p) sorted by fold, order, edges)``."""
        prep = self.prep
        pred = np.zeros((b - a, prep.n_channels))
        Js = []
        for tm in terms:
            v, J = self._eval_term(tm, a, b, x, jac=True)
            pred += v
            Js.append(J)
        J = np.concatenate(Js, axis=2) if Js else np.zeros((b - a, prep.n_channels, 0))
        if prep.kd.project:
            J = J - J.mean(1, keepdims=True)
        order, edges = self._fold_order(a, b)
        J = (J * sc[None, None, :] * np.sqrt(self.w_ch)[None, :, None])[order]
        return pred, J, order, edges

    def _fold_order(self, a: int, b: int):
        f = self.prep.fold[a:b]
        order = np.argsort(f, kind="stable")
        edges = np.searchsorted(f[order], np.arange(N_FOLDS + 1) - 0.5)
        return order, edges

    def stats(self, terms: Sequence[Term], jac: bool = True):
        """Per-fold ``(A_f, g_f, c_f, ssr_f)`` over kept rows; parameters in scaled units.

        Terms whose free parameters are all linear form a *static* block: its processed
        Jacobian and per-fold Gram matrix are cached, so a trial fit of one more candidate
        costs the products with the candidate's columns only."""
        prep = self.prep
        K = N_FOLDS
        terms = list(terms)
        static = [t for t in terms if self._linear_only(t)]
        dyn = [t for t in terms if not self._linear_only(t)]
        perm_terms = static + dyn
        p_s = sum(t.n_free() for t in static)
        p = sum(t.n_free() for t in terms)

        def scales(ts):
            return np.concatenate(
                [t.scale[q.name][t.free[q.name]].ravel() for t in ts for q in t.cand.params]
                or [np.zeros(0)]
            )

        sc_s, sc_d = scales(static), scales(dyn)
        skey = tuple(
            (
                id(t.cand),
                tuple(t.values[q.name].tobytes() for q in t.cand.params if not q.linear),
                tuple(t.free[q.name].tobytes() for q in t.cand.params),
            )
            for t in static
        )
        gram = self._gram.get(skey)
        A = np.zeros((K, p, p))
        g = np.zeros((K, p))
        c = np.zeros(K)
        ssr = np.zeros(K)
        sw = np.sqrt(self.w_ch)
        new_gram = np.zeros((K, p_s, p_s)) if gram is None else None
        for a, b, x in self._chunks():
            ck = (skey, a)
            hit = self._pcache.get(ck)
            if hit is None:
                J0 = self._processed(static, a, b, x, sc_s)
                lin = [
                    np.concatenate(
                        [t.values[q.name][t.free[q.name]].ravel() for q in t.cand.params]
                        or [np.zeros(0)]
                    )
                    for t in static
                ]
                del lin
                hit = J0
                if self._pbytes + J0[1].nbytes < CACHE_BYTES:
                    self._pcache[ck] = J0
                    self._pbytes += J0[1].nbytes
            _, Js_, order, edges = hit
            # static prediction from current linear values (v0 + J p)
            pred = np.zeros((b - a, prep.n_channels))
            for tm in static:
                pred += self._eval_term(tm, a, b, x, jac=False if not jac else True)[0]
            if dyn:
                if jac:
                    pd, Jd, _, _ = self._processed(dyn, a, b, x, sc_d)
                else:
                    pd = sum(self._eval_term(tm, a, b, x, jac=False)[0] for tm in dyn)
                    Jd = None
                pred = pred + pd
            else:
                Jd = np.zeros((b - a, prep.n_channels, 0))[order]
            r = prep.y[a:b] - pred
            if prep.kd.project:
                r = r - r.mean(1, keepdims=True)
            rw = (r * sw)[order]
            rr = r[order]
            for k in range(K):
                lo, hi = edges[k], edges[k + 1]
                if hi <= lo:
                    continue
                c[k] += float(np.sum(rw[lo:hi] ** 2))
                ssr[k] += float(np.sum(rr[lo:hi] ** 2))
                if not jac:
                    continue
                rk = rw[lo:hi].ravel()
                Sk = Js_[lo:hi].reshape(rk.size, p_s)
                g[k, :p_s] += Sk.T @ rk
                if new_gram is not None:
                    new_gram[k] += Sk.T @ Sk
                if Jd is not None and Jd.shape[2]:
                    Dk = Jd[lo:hi].reshape(rk.size, p - p_s)
                    A[k, :p_s, p_s:] += Sk.T @ Dk
                    A[k, p_s:, p_s:] += Dk.T @ Dk
                    g[k, p_s:] += Dk.T @ rk
        if jac:
            if new_gram is not None:
                gram = new_gram
                self._gram[skey] = gram
            A[:, :p_s, :p_s] = gram
            A[:, p_s:, :p_s] = np.transpose(A[:, :p_s, p_s:], (0, 2, 1))
        # back to the caller's term order
        idx = []
        pos = {}
        s0 = 0
        for t in perm_terms:
            pos[id(t)] = (s0, s0 + t.n_free())
            s0 += t.n_free()
        for t in terms:
            lo, hi = pos[id(t)]
            idx += list(range(lo, hi))
        idx = np.asarray(idx, dtype=int)
        A = A[:, idx][:, :, idx]
        g = g[:, idx]
        sc = np.concatenate([sc_s, sc_d])[idx]
        return A, g, c, ssr, sc

    def fit(self, terms: list[Term], max_steps: int = 30) -> FitResult:
        """Levenberg-Marquardt on the chunked normal equations; exact in one step for linear
        terms. Parameters that the data cannot determine (pivoted Cholesky of the scaled
        normal matrix) are held and listed."""
        terms = [t.copy() for t in terms]
        nonlinear = any(
            (not q.linear) and t.free[q.name].any() for t in terms for q in t.cand.params
        )
        lam = 1e-6
        converged = True
        A, g, c, ssr, sc = self.stats(terms)
        unident: list[str] = []
        for it in range(max_steps):
            At, gt, ct = A.sum(0), g.sum(0), c.sum()
            dz, keep_idx = _solve(At, gt, lam if nonlinear else 0.0)
            if it == 0:
                unident = _names_of(terms, np.setdiff1d(np.arange(At.shape[0]), keep_idx))
                if nonlinear:
                    # converged already (e.g. a refit from the optimum): the Gauss-Newton
                    # step's predicted decrease of chi-square is negligible
                    dz0, _ = _solve(At, gt, 0.0)
                    if float(dz0 @ gt) < min(1e-2, 1e-7 * max(ct, 1e-300)):
                        break
            new = _apply(terms, dz * sc)
            if not nonlinear:
                terms = new
                A, g, c, ssr, sc = self.stats(terms)
                break
            # the trial point's chi-square first (values only); the Jacobian only where the
            # step is taken
            _, _, c2, _, _ = self.stats(new, jac=False)
            if c2.sum() <= ct:
                rel = (ct - c2.sum()) / max(ct, 1e-300)
                terms = new
                A, g, c, ssr, sc = self.stats(new)
                lam = max(lam / 10, 1e-9)
                if rel < 1e-7 or (ct - c2.sum()) < 1e-2:
                    break
                # the next Gauss-Newton step would lower chi-square negligibly: converged
                dz1, _ = _solve(A.sum(0), g.sum(0), 0.0)
                if float(dz1 @ g.sum(0)) < min(1e-2, 1e-7 * max(c.sum(), 1e-300)):
                    break
            else:
                lam *= 10
                if lam > 1e8:
                    break
        else:
            converged = False
        return self._result(terms, A, g, c, ssr, sc, converged, unident)

    def _result(self, terms, A, g, c, ssr, sc, converged, unident) -> FitResult:
        K = A.shape[0]
        At, gt = A.sum(0), g.sum(0)
        ho_c, ho_ssr = 0.0, 0.0
        # one held-out step per fold from the full solution (exact for linear terms):
        # delta_f = (A - A_f)^+ (g - g_f); held-out chi2 = c_f - 2 delta.g_f + delta A_f delta
        _, kidx = _solve(At, gt, 0.0)
        for k in range(K):
            Ak = (At - A[k])[np.ix_(kidx, kidx)]
            gk = (gt - g[k])[kidx]
            try:
                d = sla.solve(
                    Ak + 1e-12 * np.trace(Ak) / max(len(kidx), 1) * np.eye(len(kidx)),
                    gk,
                    assume_a="pos",
                )
            except (np.linalg.LinAlgError, ValueError):
                d = np.linalg.lstsq(Ak, gk, rcond=None)[0]
            Af = A[k][np.ix_(kidx, kidx)]
            gf = g[k][kidx]
            hc = c[k] - 2 * d @ gf + d @ Af @ d
            ho_c += hc
            # unwhitened: scale by the mean channel variance ratio of this fold
            ho_ssr += ssr[k] * (hc / c[k] if c[k] > 0 else 1.0)
        p = At.shape[0]
        cov = np.full((p, p), np.nan)
        if kidx.size:
            sub = At[np.ix_(kidx, kidx)]
            try:
                inv = np.linalg.inv(sub)
            except np.linalg.LinAlgError:
                inv = np.linalg.pinv(sub)
            full = np.full((p, p), np.nan)
            full[np.ix_(kidx, kidx)] = inv
            cov = full * np.outer(sc, sc)
        slices, s = [], 0
        for t in terms:
            slices.append((s, s + t.n_free()))
            s += t.n_free()
        Apar = At / np.outer(sc, sc) if p else At
        return FitResult(
            terms=terms,
            chi2=float(c.sum()),
            n_params=int(kidx.size),
            cov=cov,
            heldout_chi2=float(ho_c),
            heldout_ssr=float(ho_ssr),
            ssr=float(ssr.sum()),
            n_rows=int(self.prep.keep.sum()),
            converged=converged,
            A=Apar,
            unidentifiable=unident,
            slices=slices,
            determined=kidx,
        )


def _solve(A: np.ndarray, g: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``(A + lam diag A) dz = g`` on the columns the data determine (pivoted Cholesky,
    relative tolerance 1e-10); the others get 0. Returns (dz, determined indices)."""
    p = A.shape[0]
    if p == 0:
        return np.zeros(0), np.zeros(0, dtype=int)
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    piv, rank = _pivoted_rank(An)
    keep = np.sort(piv[:rank])
    sub = An[np.ix_(keep, keep)] + lam * np.eye(keep.size)
    dz = np.zeros(p)
    try:
        dz[keep] = sla.solve(sub, (g / d)[keep], assume_a="pos") / d[keep]
    except (np.linalg.LinAlgError, ValueError):
        dz[keep] = np.linalg.lstsq(sub, (g / d)[keep], rcond=None)[0] / d[keep]
    return dz, keep


def _pivoted_rank(An: np.ndarray, tol: float = 1e-10) -> tuple[np.ndarray, int]:
    from scipy.linalg import lapack

    c, piv, rank, info = lapack.dpstrf(np.array(An, order="F"), tol=tol, lower=0)
    zero_diag = np.diag(An) < 1e-200
    piv = piv - 1
    rank = int(rank)
    if zero_diag.any():
        good = [i for i in piv[:rank] if not zero_diag[i]]
        rest = [i for i in piv if i not in good]
        piv = np.array(good + rest)
        rank = len(good)
    return piv, rank


def _apply(terms: list[Term], dz: np.ndarray) -> list[Term]:
    out = []
    s = 0
    for t in terms:
        t2 = t.copy()
        for q in t.cand.params:
            m = t.free[q.name]
            k = int(m.sum())
            v = t2.values[q.name]
            v[m] = v[m] + dz[s : s + k]
            s += k
        out.append(t2)
    return out


def _names_of(terms: list[Term], idx: np.ndarray) -> list[str]:
    names = []
    s = 0
    idx = set(int(i) for i in idx)
    for t in terms:
        for q in t.cand.params:
            m = t.free[q.name]
            pos = np.argwhere(m)
            for j, ij in enumerate(pos):
                if s + j in idx:
                    ij_s = [int(v) for v in ij]
                    names.append(f"{t.cand.name}.{q.name}{ij_s if ij_s else ''}")
            s += int(m.sum())
    return names


# ----------------------------------------------------------------------------- goodness of fit


def _row_chi2(resid: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """``sum_c (resid / sigma_c)^2`` per row (n,), in blocks (no (n, C) temporary)."""
    out = np.empty(resid.shape[0])
    w = 1.0 / np.asarray(sigma, float) ** 2
    for a in range(0, resid.shape[0], SCAN_BLOCK):
        r = resid[a : a + SCAN_BLOCK]
        out[a : a + SCAN_BLOCK] = (r * r) @ w
    return out


def goodness_of_fit(prep: Prepared, resid: np.ndarray, n_params: int) -> dict:
    """Variance-ratio test of the residual against the noise level.

    ``z = log(s_r^2) / sqrt(v / N)`` with ``s_r^2`` the residual variance per fitted value
    (dof-corrected) whitened by the noise per channel (the periodogram-median estimate,
    :func:`noise_spectral`, which structure in fewer than half the frequency bins cannot
    inflate), and ``v = 2 + 2 MEDIAN_VAR`` (residual and noise estimate treated as
    independent: conservative). Under white noise ``z ~ N(0, 1)``; structure the model misses
    raises ``s_r^2``. Applied to the whole record and to each time block of each run
    (Bonferroni); ``p`` is the smaller of the two (times 2).
    """
    keep = prep.keep
    q = _row_chi2(resid, prep.sigma)  # whitened chi-square per row (n,)
    C = prep.n_channels
    eff = (C - 1) / C if prep.kd.project and C > 1 else 1.0
    N = float(keep.sum() * C * eff)
    v = 2.0 + 2.0 * MEDIAN_VAR / eff
    sr = float(np.sum(q, where=keep)) / max(N - n_params, 1.0)
    z = math.log(sr) / math.sqrt(v / max(N, 1.0))
    p_global = float(stats.norm.sf(z))
    blocks = []
    for r in range(prep.ctx.n_runs):
        rows = np.flatnonzero((prep.run == r) & keep)
        nb = int(min(16, max(1, rows.size // 64)))
        for part in np.array_split(rows, nb):
            if part.size < 16:
                continue
            Nb = part.size * C * eff
            srb = float(np.sum(q[part])) / max(Nb * (1 - n_params / max(N, 1)), 1.0)
            zb = math.log(max(srb, 1e-300)) / math.sqrt(2.0 / Nb + (v - 2.0) / N)
            blocks.append(
                (
                    float(stats.norm.sf(zb)),
                    zb,
                    int(prep.run_ids[r]),
                    float(prep.rows["t"][part[0]]),
                    float(prep.rows["t"][part[-1]]),
                )
            )
    nbk = max(len(blocks), 1)
    worst = min(blocks, default=(1.0, 0.0, 0, 0.0, 0.0))
    p_block = min(1.0, worst[0] * nbk)
    p = min(1.0, 2 * min(p_global, p_block))
    return {
        "test": "variance ratio of the whitened residual to the noise (median of the "
        "periodogram per channel); log ratio ~ N(0, v/N) under white noise, whole record and "
        "per time block (16 per run, Bonferroni)",
        "statistic_z": z,
        "variance_ratio": sr,
        "p_value": p,
        "p_value_whole": p_global,
        "p_value_blocks": p_block,
        "worst_block": {
            "run": worst[2],
            "t_start_s": worst[3],
            "t_end_s": worst[4],
            "z": worst[1],
        },
        "n_values": N,
        "n_params": n_params,
        "alpha": ALPHA,
        "passes": bool(p >= ALPHA),
    }


# ----------------------------------------------------------------------------- selection


@dataclasses.dataclass
class Step:
    """One accepted (or tried) candidate."""

    name: str
    fit: FitResult
    delta_bic: float
    delta_heldout: float
    collinearity: float
    notes: list[str]
    term_rms: float
    explained_rms: float
    confounded: list[dict] = dataclasses.field(default_factory=list)


def _tie(
    fitter: Fitter, prep: Prepared, cur_resid: np.ndarray, a: FitResult, b: FitResult
) -> tuple[float, float]:
    """``(chi-square gap, correlation)`` of two alternative fits ``a`` (chosen) and ``b``:
    how much better ``a`` fits, and the correlation of what each takes out of the current
    residual (kept rows, noise-whitened). Near 0 and near 1: the data cannot tell them."""
    keep = prep.keep
    w = 1.0 / prep.sigma[None, :]
    saa = sbb = sab = 0.0
    for lo, hi, x in fitter._chunks():  # one pass: both fits on each chunk
        ra = fitter.chunk_residual(a.terms, lo, hi, x)
        rb = fitter.chunk_residual(b.terms, lo, hi, x)
        k = keep[lo:hi]
        ca = ((cur_resid[lo:hi] - ra) * w)[k]
        cb = ((cur_resid[lo:hi] - rb) * w)[k]
        saa += float(np.sum(ca * ca))
        sbb += float(np.sum(cb * cb))
        sab += float(np.sum(ca * cb))
    den = math.sqrt(saa * sbb)
    corr = float(abs(sab) / den) if den > 0 else 0.0
    return float(b.chi2 - a.chi2), corr


def _collinearity(fit: FitResult, n_base_terms: int) -> float:
    """Largest canonical correlation between the last term's columns and the base's."""
    s0, s1 = fit.slices[-1]
    base_n = fit.slices[n_base_terms - 1][1] if n_base_terms else 0
    A = fit.A
    p = A.shape[0]
    if s1 <= s0 or base_n == 0:
        return 0.0
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    b = np.arange(base_n)
    e = np.arange(s0, s1)
    Abb, Aee, Abe = An[np.ix_(b, b)], An[np.ix_(e, e)], An[np.ix_(b, e)]
    try:
        Lb = np.linalg.pinv(Abb, rcond=1e-10, hermitian=True)
        Le = np.linalg.pinv(Aee, rcond=1e-10, hermitian=True)
    except np.linalg.LinAlgError:
        return float("nan")
    M = Le @ Abe.T @ Lb @ Abe
    ev = np.linalg.eigvals(M).real
    del p
    return float(math.sqrt(min(max(ev.max(initial=0.0), 0.0), 1.0)))


def _collinear_columns(fit: FitResult, n_base_terms: int) -> np.ndarray:
    """Local indices (in the last term's free vector) to hold so that the rest of the term
    has a canonical correlation with the base model's columns of at most
    ``COLLINEAR_REFUSE``: greedily, the column best explained by the base and the columns
    kept so far first."""
    s0, s1 = fit.slices[-1]
    base_n = fit.slices[n_base_terms - 1][1] if n_base_terms else 0
    if s1 <= s0 or base_n == 0:
        return np.zeros(0, int)
    A = fit.A
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    b = np.arange(base_n)
    Lb = np.linalg.pinv(An[np.ix_(b, b)], rcond=1e-10, hermitian=True)
    keep = list(range(s0, s1))
    held: list[int] = []
    for _ in range(s1 - s0):
        e = np.asarray(keep)
        Aee, Abe = An[np.ix_(e, e)], An[np.ix_(b, e)]
        Le = np.linalg.pinv(Aee, rcond=1e-10, hermitian=True)
        ev = np.linalg.eigvals(Le @ Abe.T @ Lb @ Abe).real
        if ev.size == 0 or ev.max() <= COLLINEAR_REFUSE**2:
            break
        r2 = np.einsum("bj,bc,cj->j", Abe, Lb, Abe)
        j = int(np.argmax(r2))
        held.append(keep.pop(j) - s0)
        if not keep:
            break
    return np.asarray(sorted(held), int)


def _hold(term: Term, local: np.ndarray) -> Term:
    """``term`` with the free scalars at ``local`` (free-vector indices) held at zero."""
    t2 = term.copy()
    pos = 0
    local = set(int(i) for i in local)
    for q in t2.cand.params:
        m = t2.free[q.name]
        flat = m.ravel()
        v = t2.values[q.name].ravel()
        for j in np.flatnonzero(flat):
            if pos in local:
                flat[j] = False
                v[j] = 0.0
            pos += 1
        t2.free[q.name] = flat.reshape(m.shape)
        t2.values[q.name] = v.reshape(m.shape)
    return t2


def _local_names(held_term: Term, local: np.ndarray, fitted: Term) -> list[str]:
    del fitted
    names = []
    for q in held_term.cand.params:
        m = held_term.free[q.name]
        for ij in np.argwhere(~m):
            names.append(f"{q.name}{[int(v) for v in ij] if ij.size else ''}")
    del local
    return names


def _frozen(terms: list[Term]) -> list[Term]:
    """Copies with the nonlinear parameters held (trial fits: one matrix product each)."""
    out = []
    for t in terms:
        t2 = t.copy()
        for q in t.cand.params:
            if not q.linear:
                t2.free[q.name][...] = False
        out.append(t2)
    return out


def _unfrozen(terms: list[Term], like: list[Term]) -> list[Term]:
    """``terms`` with the free masks of ``like`` (same order and names)."""
    out = []
    for t, l in zip(terms, like):
        t2 = t.copy()
        t2.free = {k: v.copy() for k, v in l.free.items()}
        out.append(t2)
    return out


def _term_rms(fitter: Fitter, term: Term, prep: Prepared) -> float:
    """RMS of one term's own contribution (projected, whitened by the noise)."""
    tot = 0.0
    for a, b, x in fitter._chunks():  # chunk by chunk: nothing per row is held
        v = fitter._eval_term(term, a, b, x, jac=False)[0]
        if prep.kd.project:
            v = v - v.mean(1, keepdims=True)
        tot += float(np.sum((v[prep.keep[a:b]] / prep.sigma[None, :]) ** 2))
    C = prep.n_channels
    eff = (C - 1) / C if prep.kd.project else 1.0
    return float(np.sqrt(tot / max(prep.keep.sum() * C * eff, 1)))


def _step_fn(p: dict, x: dict):
    on = jnp.where(x["tau"] >= p["tau_s"], 1.0, 0.0) * (x["run_onehot"] @ p["run_sel"])
    return p["size"] * on[:, None] * p["channel_sel"][None, :]


STEP_NUISANCE = Candidate(
    name="located_step",
    fn=_step_fn,
    params=(
        Param("size", "unit of y", scale=None, description="size of the step"),
        Param("tau_s", "s", linear=False, fit=False, description="global time of the step"),
        Param("run_sel", "1", shape="runs", linear=False, fit=False),
        Param("channel_sel", "1", shape="channels", linear=False, fit=False),
    ),
    explanation="a step located in time (no catalog effect: the alternative a candidate "
    "must beat where the time view located a step)",
)
"""A step of one size on the channels of a located step, from its row on within its run."""
STEP_CHANGE_ROWS = 3
"""A located step within this many kept rows (or half a time-view block) of a change of
direction or speed is one the catalog's direction / speed terms can make."""


def _free_steps(prep: Prepared, findings: list) -> list[dict]:
    """Steps the time view located at a time where nothing the catalog knows changes.

    A direction offset (backlash, hysteresis) is a step at a reversal and a reading delay a
    step where the speed changes: a located step within ``STEP_CHANGE_ROWS`` kept rows (or
    half a time-view block, 1/64 of the run) of a kept row where the direction or the
    steady speed changes is left to those terms. The others are steps no smooth term (a
    drift, a scale error, an order) can make; each is returned with its time, run and
    channels."""
    out = []
    keep = prep.keep
    for f in findings:
        if f.view != "time" or not (
            f.detail.get("shape") == "step" or f.detail.get("step_significant")
        ):
            continue
        if len(out) >= 2:
            break
        r = int(np.flatnonzero(prep.run_ids == f.where["runs"][0])[0])
        rows = np.flatnonzero((prep.run == r) & keep)
        tau0 = float(f.detail["global_step_time_s"])
        i = int(np.searchsorted(prep.rows.take("tau", rows), tau0))
        if i <= 0 or i >= rows.size:
            continue
        # kept rows where the direction or the steady speed changes (a reversal or a speed
        # change, with the non-steady rows between them left out)
        d = np.asarray(prep.rows.take("direction", rows), float)
        w = np.asarray(prep.rows.take("omega", rows), float)
        ch_rows = (
            np.flatnonzero(
                (d[1:] != d[:-1])
                | (np.abs(w[1:] - w[:-1]) > 0.05 * np.maximum(np.abs(w[1:]), np.abs(w[:-1])))
            )
            + 1
        )
        near = max(STEP_CHANGE_ROWS, rows.size // 64)
        if ch_rows.size and np.min(np.abs(ch_rows - i)) <= near:
            continue
        ch = np.zeros(prep.n_channels)
        ch[list(f.where["heads"])] = 1.0
        sel = np.zeros(prep.ctx.n_runs)
        sel[r] = 1.0
        out.append(dict(tau_s=tau0, run=r, channels=ch, run_sel=sel, finding=f))
    return out


def _step_term(prep: Prepared, step: dict) -> Term:
    tm = make_term(
        STEP_NUISANCE,
        prep,
        {"tau_s": step["tau_s"], "run_sel": step["run_sel"], "channel_sel": step["channels"]},
    )
    tm.scale["size"][...] = float(np.mean(prep.sigma))
    return tm


def _beaten_by_step(
    fitter: Fitter,
    prep: Prepared,
    current: FitResult,
    fr: FitResult,
    steps: list[dict],
    cache: dict,
) -> tuple[str, Any] | None:
    """``(why, the step's finding)`` when a candidate ``fr`` (current model plus the
    candidate) is refused for a located step it cannot make, or ``None``: fitted together
    with the step, the step still earns its place and the candidate no longer does
    (information criterion or held-out)."""
    if not steps:
        return None
    N = prep.n_values
    logn = math.log(max(N, 2))
    k = max(fr.n_determined(len(fr.terms) - 1), 0)
    base_terms = _frozen(current.terms)
    cand = _frozen(fr.terms[-1:])
    for st in steps:
        key = (st["tau_s"], st["run"], tuple(st["channels"]))
        if key not in cache:
            cache[key] = fitter.fit([*base_terms, _step_term(prep, st)])
        f = st["finding"]
        for attempt in range(2):
            fs = cache[key]
            both = fitter.fit([*base_terms, _step_term(prep, st), *cand])
            if fr.chi2 - both.chi2 < BIC_MIN + logn:
                break  # with the candidate there is no step left: it makes it
            dchi = fs.chi2 - both.chi2
            dbic = -(dchi - k * logn)
            dho = fs.heldout_chi2 - both.heldout_chi2
            if dbic > -BIC_MIN or dho < HELDOUT_MIN:
                heads = [prep.kd.channel_names[h] for h in f.where["heads"]]
                return (
                    f"a step located at t = {f.detail['step_time_s']:.6g} s (run "
                    f"{f.where['runs'][0]}, {', '.join(heads)}) explains what it explains: "
                    f"fitted with that step it lowers chi-square by {dchi:.1f} only (dBIC "
                    f"{dbic:.1f}, held-out {dho:.1f}); it cannot make a step there (no "
                    "reversal, no change of speed at that time)",
                    f,
                )
            if attempt:
                break
            # the step still leaves it something: a step placed a few rows off leaves a box
            # a smooth term takes part of; the step's row from base + step fits, once
            rkey = ("refined", key)
            if rkey not in cache:
                g = dataclasses.replace(f, where=dict(f.where), detail=dict(f.detail))
                _refine_step(fitter, prep, current.terms, g)
                st2 = dict(st, tau_s=g.detail["global_step_time_s"], finding=g)
                cache[rkey] = st2
            st2 = cache[rkey]
            if st2["tau_s"] == st["tau_s"]:
                break
            st, f = st2, st2["finding"]
            key = (st["tau_s"], st["run"], tuple(st["channels"]))
            if key not in cache:
                cache[key] = fitter.fit([*base_terms, _step_term(prep, st)])
    return None


def _refine_step(fitter: Fitter, prep: Prepared, terms: list[Term], f) -> None:
    """Move a located step's time (``f``, a ``time`` finding) to the row where the model
    ``terms`` plus a step fits best: the time view's change point is read off a residual
    from which the base model has taken part of the step (and moved its change point). A
    scan of 32 rows over 4 time-view blocks (1/8 of the run) either side, then of the rows
    between the best one's neighbours (at most 48)."""
    r = int(np.flatnonzero(prep.run_ids == f.where["runs"][0])[0])
    rows = np.flatnonzero((prep.run == r) & prep.keep)
    tau = prep.rows.take("tau", rows)
    ch = np.zeros(prep.n_channels)
    ch[list(f.where["heads"])] = 1.0
    sel = np.zeros(prep.ctx.n_runs)
    sel[r] = 1.0
    held = _frozen(terms)

    def chi2(i: int) -> float:
        st = dict(tau_s=float(tau[i]), channels=ch, run_sel=sel)
        return fitter.fit([*held, _step_term(prep, st)]).chi2

    # within 4 time-view blocks of the located row: a step and its mirror image about a
    # reversal differ by a function of the angle, which the base model takes (the two
    # times cannot be told apart over a turn back and forth); the located one is kept
    i0 = int(np.searchsorted(tau, f.detail["global_step_time_s"]))
    width = max(int(4 * rows.size / 32), 4)
    lo, hi = max(i0 - width, 1), min(i0 + width, rows.size - 1)
    grid = np.unique(np.linspace(lo, hi, 32).astype(int))
    best = min(grid, key=chi2)
    k = int(np.searchsorted(grid, best))
    a = int(grid[max(k - 1, 0)])
    b = int(grid[min(k + 1, grid.size - 1)])
    fine = np.arange(a, b + 1)
    if fine.size > 48:
        fine = np.unique(np.linspace(a, b, 48).astype(int))
    best = int(min(fine, key=chi2))
    t = prep.rows["t"]
    f.detail["step_time_s"] = float(t[rows[best]])
    f.detail["global_step_time_s"] = float(tau[best])
    f.detail["step_times_s"] = [float(t[rows[best - 1]]), float(t[rows[best]])]


UNTOUCHED_SHARE = 0.8
"""An integer order whose located power a candidate leaves at this share or more is not
the candidate's (the signature rule of :func:`select` does not count it)."""


def _order_key(f) -> int | None:
    """The integer order a finding is at (the ``orders`` view, or a spectrum line at an
    integer order), else None."""
    integer = f.view == "orders" or (f.view == "spectrum" and f.detail.get("integer_order"))
    ints = {round(o) for o in f.where.get("orders", []) if math.isfinite(o)}
    return ints.pop() if integer and len(ints) == 1 else None


def _untouched_orders(before, after) -> set:
    """Integer orders located before a candidate's fit that keep at least
    ``UNTOUCHED_SHARE`` of their excess power after it."""
    p0: dict = {}
    p1: dict = {}
    for fs, acc in ((before, p0), (after, p1)):
        for f in fs:
            k = _order_key(f)
            if k is not None:
                acc[k] = acc.get(k, 0.0) + max(f.power - f.dof, 0.0)
    return {k for k, v in p0.items() if v > 0 and p1.get(k, 0.0) >= UNTOUCHED_SHARE * v}


def select(
    prep: Prepared,
    fitter: Fitter,
    base_terms: list[Term],
    candidates: Sequence[Candidate],
    views: tuple[str, ...],
    scan_order: int,
    max_effects: int = 3,
    log: Callable[[str], None] = lambda s: None,
):
    """Forward selection with refits, then a backward held-out check (stage 4)."""
    base = fitter.fit(base_terms)
    cur_resid = fitter.residual(base.terms)
    findings0 = locate(prep, cur_resid, views, scan_order)
    N = prep.n_values
    current, findings = base, findings0
    accepted: list[Step] = []
    rejected: list[dict] = []
    not_testable: list[dict] = []
    n_base_terms = len(base.terms)
    tried_names: set[str] = set()
    applicable = []
    for c in candidates:
        why = c.applies(prep.ctx) if c.applies else None
        if why:
            not_testable.append({"name": c.name, "reason": why})
        else:
            applicable.append(c)
    gof0 = goodness_of_fit(prep, cur_resid, current.n_params)
    held_notes: dict[str, list[str]] = {}
    step_refusals: list[tuple[str, Any]] = []
    for _ in range(max_effects):
        seen = {f.view for f in findings}
        gof = goodness_of_fit(prep, cur_resid, current.n_params)
        if not findings and gof["passes"]:
            break
        trials = []
        kept_resid = None  # the current residual over the kept rows, made once per round
        free_steps = _free_steps(prep, findings)
        step_fits: dict = {}
        for cand in applicable:
            if cand.name in {s.name for s in accepted}:
                continue
            if cand.signature and not (set(cand.signature) & seen):
                continue
            if not cand.signature and gof["passes"]:
                continue
            tried_names.add(cand.name)
            if cand.start and kept_resid is None:
                kept_resid = cur_resid if prep.keep.all() else cur_resid[prep.keep]
            starts = cand.start(prep.ctx, kept_resid, findings) if cand.start else [{}]
            best = None
            # screen the starts with the nonlinear parameters held (one linear pass each),
            # then run the full fit from the best one
            screened = []
            for st in starts[:4]:
                term = make_term(cand, prep, st)
                if prep.n_values - current.n_params - term.n_free() < 0 or (
                    current.n_params + term.n_free() > MAX_PARAM_FRACTION * N
                ):
                    rejected.append(
                        {
                            "name": cand.name,
                            "reason": "more parameters than "
                            f"{MAX_PARAM_FRACTION:.0%} of the fitted values",
                        }
                    )
                    break
                if len(starts) > 1:
                    held = _frozen([term])[0]
                    fr0 = fitter.fit([*_frozen(current.terms), held])
                    screened.append((fr0.chi2, term, fr0))
                else:
                    screened.append((0.0, term, None))
            if screened:
                screened.sort(key=lambda z: z[0])
                term = screened[0][1]
                if screened[0][2] is not None:
                    term = _unfrozen(screened[0][2].terms[-1:], [term])[0]
                log(f"trying {cand.name}")
                best = fitter.fit([*_frozen(current.terms), term], max_steps=12)
                # columns of the candidate the base model already spans are held at zero
                # (reported), so the rest of it can still be tested
                held = _collinear_columns(best, n_base_terms)
                if held.size and held.size < best.terms[-1].n_free():
                    t2 = _hold(best.terms[-1], held)
                    best = fitter.fit([*_frozen(current.terms), t2], max_steps=12)
                    held_notes[cand.name] = _local_names(t2, held, best.terms[-1])
            if best is None:
                continue
            dchi = current.chi2 - best.chi2
            k = best.n_determined(len(best.terms) - 1)
            dbic = -(dchi - max(k, 0) * math.log(max(N, 2)))
            dho = current.heldout_chi2 - best.heldout_chi2
            trials.append((dbic, cand, best, dho, dchi, k))
        trials.sort(key=lambda x: x[0])
        # candidates equal to rounding (the same fitted error, e.g. an offset per direction
        # and a delay at one speed), wherever they stand in the order: the catalog's order
        # decides, not the last digit
        rank = {c.name: i for i, c in enumerate(applicable)}
        g0 = 0
        while g0 < len(trials):
            tol = 1e-7 * max(1.0, abs(trials[g0][0]))
            g1 = g0 + 1
            while g1 < len(trials) and trials[g1][0] - trials[g0][0] <= tol:
                g1 += 1
            trials[g0:g1] = sorted(trials[g0:g1], key=lambda x: rank[x[1].name])
            g0 = g1
        kept_resid = None
        chosen = None
        for dbic, cand, fr, dho, dchi, k_new in trials:
            reasons = []
            if k_new == 0:
                rejected.append(
                    {
                        "name": cand.name,
                        "reason": "confounded: all its parameters are already taken by the base "
                        f"model or by {', '.join(s.name for s in accepted) or 'nothing else'} "
                        "(shared orders go to the effect accepted first)",
                    }
                )
                continue
            if dbic > -BIC_MIN:
                reasons.append(f"information criterion not lowered enough (dBIC {dbic:.1f})")
            if dho < HELDOUT_MIN:
                reasons.append(
                    f"held-out chi-square lowered by {dho:.1f} only (needs {HELDOUT_MIN:.0f})"
                )
            term = fr.terms[-1]
            trms = _term_rms(fitter, term, prep)
            erms = math.sqrt(max(dchi, 0.0) / max(N, 1))
            if trms > PLAUSIBLE_RATIO * max(erms, 1e-300) and trms > 1.0:
                reasons.append(
                    f"implausible: its own size ({trms:.3g} noise units RMS) is over "
                    f"{PLAUSIBLE_RATIO:.0f}x the residual it explains ({erms:.3g})"
                )
            col = _collinearity(fr, n_base_terms)
            if np.isfinite(col) and col > COLLINEAR_REFUSE:
                reasons.append(
                    f"ill-conditioned against the base model (canonical correlation {col:.4f})"
                )
            if cand.plausible is not None:
                why = cand.plausible(prep.ctx, term.values)
                if why:
                    reasons.append(f"implausible: {why}")
            if reasons:
                rejected.append(
                    {"name": cand.name, "reason": "; ".join(reasons), "delta_bic": float(dbic)}
                )
                continue
            if chosen is not None:
                gap, corr = _tie(fitter, prep, cur_resid, chosen[1], fr)
                if gap < TIE_CHI2 and corr > TIE_CORR:
                    # not decided by the criterion: reported with the chosen one
                    chosen[8].append(
                        {
                            "name": cand.name,
                            "reason": f"the data cannot tell it from {chosen[0].name}: it "
                            f"fits as well (chi-square {gap:+.1f}, needs {TIE_CHI2:.0f} to "
                            f"decide) and its fitted error is the same (correlation "
                            f"{corr:.3f})",
                            "delta_bic": float(dbic),
                            "params": {
                                q.name: _jsonable(fr.terms[-1].values[q.name]) for q in cand.params
                            },
                        }
                    )
                    continue
                rejected.append(
                    {
                        "name": cand.name,
                        "reason": f"{chosen[0].name} lowers the "
                        f"criterion more (dBIC {chosen[2]:.1f} vs {dbic:.1f})",
                        "delta_bic": float(dbic),
                    }
                )
                continue
            # it must explain a fair share of everything located, so that a larger
            # structure it cannot explain is not pinned on it through a small part of it
            p0 = sum(f.power - f.dof for f in findings)
            steps_left: list[dict] = []
            if p0 > 0:
                after = locate(prep, fitter.residual(fr.terms), views, scan_order)
                # steps it leaves (a smooth model fitted to a step moves its change point)
                steps_left = _free_steps(prep, after)
                p1 = sum(f.power - f.dof for f in after)
                # and clear the places its own signature located (not a larger structure
                # there that it only dents, e.g. a step fitted by a drift)
                sig = set(cand.signature) or {f.view for f in findings}
                # an integer order it leaves untouched is another effect's (several
                # effects at once share the views), not structure it only dents
                left = _untouched_orders(findings, after)
                m0 = sum(
                    f.power - f.dof for f in findings if f.view in sig and _order_key(f) not in left
                )
                m1 = sum(
                    f.power - f.dof for f in after if f.view in sig and _order_key(f) not in left
                )
                if m0 > 0 and m1 > SIGNATURE_LEFT_MAX * m0:
                    rejected.append(
                        {
                            "name": cand.name,
                            "reason": f"leaves {100 * m1 / m0:.0f}% of the structure its "
                            f"signature views ({', '.join(sorted(sig))}) located in place",
                            "delta_bic": float(dbic),
                        }
                    )
                    continue
                if p1 > (1.0 - LOCATED_SHARE_MIN) * p0:
                    rejected.append(
                        {
                            "name": cand.name,
                            "reason": f"explains only {100 * (1 - p1 / p0):.0f}% of the located "
                            f"structure (needs {100 * LOCATED_SHARE_MIN:.0f}%)",
                            "delta_bic": float(dbic),
                        }
                    )
                    continue
            # a step located where nothing in the catalog changes (no reversal, no change of
            # speed) is the alternative it must beat: a drift or a scale error only dents it
            why = _beaten_by_step(fitter, prep, current, fr, free_steps + steps_left, step_fits)
            if why:
                rejected.append({"name": cand.name, "reason": why[0], "delta_bic": float(dbic)})
                step_refusals.append((cand.name, why[1]))
                continue
            notes = []
            if held_notes.get(cand.name):
                notes.append(
                    "held at zero, already spanned by the base model (canonical correlation "
                    f"> {COLLINEAR_REFUSE}): {', '.join(held_notes[cand.name][:12])}"
                )
            if col > COLLINEAR_NOTE:
                notes.append(
                    f"nearly collinear with the base model (canonical correlation "
                    f"{col:.3f}): part of it could be absorbed by base parameters"
                )
            chosen = (cand, fr, dbic, dho, col, notes, trms, erms, [])
        if chosen is None:
            break
        cand, fr, dbic, dho, col, notes, trms, erms, confounded = chosen
        if confounded:
            notes = [
                *notes,
                "confounded with "
                + ", ".join(c["name"] for c in confounded)
                + ": this recording cannot tell them apart; the name is only the one with "
                "the lower information criterion",
            ]
        full = fitter.fit(_unfrozen(fr.terms[:-1], current.terms) + fr.terms[-1:])
        if full.chi2 <= fr.chi2:
            fr = full
        del cur_resid  # (one residual held at a time)
        resid = fitter.residual(fr.terms)
        accepted.append(Step(cand.name, fr, dbic, dho, col, notes, trms, erms, confounded))
        log(f"named {cand.name}")
        current, cur_resid = fr, resid
        findings = locate(prep, cur_resid, views, scan_order)
    # backward check: each named effect must still earn its place on held-out data (the
    # others held at their nonlinear values: one linear refit each)
    without: dict[str, FitResult] = {}
    if len(accepted) > 1:
        for s in list(accepted):
            others = _frozen([t for t in current.terms if t.cand.name != s.name])
            fr = fitter.fit(others)
            without[s.name] = fr
            if fr.heldout_chi2 - current.heldout_chi2 < HELDOUT_MIN:
                accepted.remove(s)
                rejected.append(
                    {
                        "name": s.name,
                        "reason": "backward check: with the other "
                        "named effects it no longer lowers the held-out residual",
                    }
                )
                current = fitter.fit(
                    _unfrozen(fr.terms, [t for t in current.terms if t.cand.name != s.name])
                )
                cur_resid = fitter.residual(current.terms)
                findings = locate(prep, cur_resid, views, scan_order)
                without = {}
    # a step that refused a candidate is reported where it was located (a smooth base or
    # effect fitted to it moves the change point the final residual's time view sees)
    done: set = set()
    for name, f in step_refusals:
        key = (tuple(f.where["runs"]), tuple(f.where["heads"]))
        if key in done:  # one refined step per run and heads: the first refusal's
            continue
        done.add(key)
        ts = f.detail["step_time_s"]
        seen = [
            g
            for g in findings
            if g.view == "time"
            and g.detail.get("shape") == "step"
            and g.where["runs"] == f.where["runs"]
            and min(g.where["times_s"]) - 4 * g.detail["block_s"]
            <= ts
            <= max(g.where["times_s"]) + 4 * g.detail["block_s"]
        ]
        if seen:  # the final residual's own step: refined with the final model
            _refine_step(fitter, prep, current.terms, seen[0])
            seen[0].where["times_s"] = list(seen[0].detail["step_times_s"])
            continue
        _refine_step(fitter, prep, current.terms, f)
        f.where["times_s"] = list(f.detail["step_times_s"])
        f.detail["shape"] = "step"
        if not any(h is f for h in findings):  # else a finding of the final residual
            f.detail["located_with"] = f"located in the residual of the model with {name}"
            findings = sorted([*findings, f], key=lambda g: g.log10_p)
    # shares: what each effect explains given the others
    shares = {}
    total = base.chi2 - current.chi2
    for s in accepted:
        fr = without.get(s.name)
        if fr is None:
            others = _frozen([t for t in current.terms if t.cand.name != s.name])
            fr = fitter.fit(others) if len(accepted) > 1 else base
        shares[s.name] = float((fr.chi2 - current.chi2) / total) if total > 0 else 0.0
    return dict(
        base=base,
        # the base residual again (one pass): not held through the selection
        base_resid=cur_resid if current is base else fitter.residual(base.terms),
        findings0=findings0,
        gof0=gof0,
        final=current,
        final_resid=cur_resid,
        findings=findings,
        accepted=accepted,
        rejected=rejected,
        not_testable=not_testable,
        shares=shares,
        tried=sorted(tried_names),
    )


# ----------------------------------------------------------------------------- run + JSON


def _jsonable(v):
    a = np.asarray(v, float)
    a = np.where(np.isfinite(a), a, np.nan)
    if a.ndim == 0:
        return None if np.isnan(a) else float(a)
    return [_jsonable(x) for x in a]


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
        out[q.name] = {"value": _jsonable(term.values[q.name]), "se": _jsonable(se), "unit": q.unit}
    return out


def _se_dict(term: Term, fit: FitResult, index: int) -> dict[str, np.ndarray]:
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


def _scan_order(limit: int, order: int) -> int:
    """Highest order the views scan for a base of ``order``: twice it, at least 24, within
    what the record resolves."""
    return int(min(limit, max(2 * order, 24)))


GROWTH_LEFT_MAX = 0.2
"""The grown base must leave at most this share of the structure the views located (excess
chi-square over their degrees of freedom) in the base residual, or the growth is undone."""


def _grow_base_order(
    kind: Kind,
    prep: Prepared,
    fitter: Fitter,
    fit: FitResult,
    order: int,
    limit: int,
    base_info: dict,
):
    """Integer orders above ``order`` that the base residual shows significantly (the
    ``orders`` view, up to ``min(limit, max(2 order, 24))``) join the base model: a disk's
    error function has every order, and one left out would be reported as structure no
    effect explains. Not when the residual also shows a line at the signal period (aliased,
    it can pose as integer orders) or structure tied to the direction or speed (the
    candidates' to explain); and the grown base must leave at most ``GROWTH_LEFT_MAX`` of
    what every view located (a line in Hz, a step or a drift that only leaks into high orders
    stays the candidates'; a strong order's leakage into lines off the integers goes with it).
    Orders ``L`` and ``2 L`` of the signal period
    (``interpolation_error``'s) stay out. Returns ``(order, fit)``, grown and refitted from
    the fitted values, or ``None`` (nothing changed)."""
    hi = _scan_order(limit, order)
    if hi <= order:
        return None
    L = int(getattr(prep.ctx, "signal_periods", 0) or 0)
    findings = locate(prep, fitter.residual(fit.terms), kind.views, hi)
    if any(f.view in ("line_phase", "direction", "speed", "angle_trend") for f in findings):
        return None
    found = [
        round(f.where["orders"][0])
        for f in findings
        if f.view == "orders" and f.where["orders"] and round(f.where["orders"][0]) > order
    ]
    found = [m for m in found if not (L > 0 and m in (L, 2 * L))]
    if not found:
        return None
    M = int(max(found))
    spec, info = kind.base(prep, M)
    old = {t.cand.name: t for t in fit.terms}
    terms = []
    for cand, start in spec:
        prev = old.get(cand.name)
        st = dict(start)
        if prev is not None:
            for q in cand.params:
                v = prev.values.get(q.name)
                if v is None:
                    continue
                shp = q.resolved_shape(prep.n_channels, prep.ctx.n_runs)
                if v.shape == shp:
                    st[q.name] = v
                elif v.ndim == 1 and len(shp) == 1 and v.size < shp[0]:
                    st[q.name] = np.concatenate([v, np.zeros(shp[0] - v.size)])
        tm = make_term(cand, prep, st)
        for q in cand.params:
            if q.scale is None:
                tm.scale[q.name][...] = float(np.mean(prep.sigma))
        terms.append(tm)
    prep.consts["max_order"] = M  # type: ignore[index]
    fitter.clear()
    grown = fitter.fit(terms)
    p0 = sum(max(f.power - f.dof, 0.0) for f in findings)
    after = locate(prep, fitter.residual(grown.terms), kind.views, _scan_order(limit, M))
    p1 = sum(max(f.power - f.dof, 0.0) for f in after)
    if p1 > GROWTH_LEFT_MAX * p0:
        prep.consts["max_order"] = order  # type: ignore[index]
        fitter.clear()
        return None
    base_info.update({k: v for k, v in info.items() if k not in ("refine",)})
    base_info["grown_orders"] = sorted(set(base_info.get("grown_orders", [])) | set(found))
    return M, grown


def run_engine(
    kind: Kind,
    rec,
    *,
    max_order: int | None = None,
    max_effects: int = 3,
    extra_candidates: Sequence[Candidate] = (),
    verbose: bool = False,
) -> dict[str, Any]:
    """Diagnose ``rec`` with ``kind``; returns the diagnosis JSON document (a dict).

    Raises:
        EncdesignInputError: a recording the kind cannot diagnose, or ``max_order`` beyond
            what the record resolves.
    """
    from .._progress import progress_bar

    t0 = time.perf_counter()
    # a tqdm bar on a terminal only (quiet in pipes, logs and tests), through every stage
    bar = progress_bar("diagnose", 6, enabled=verbose, unit="stage")

    def stage(name: str) -> None:
        bar.set_postfix_str(name)
        bar.update(1)

    bar.set_postfix_str("preparing")
    kd = kind.data(rec)
    meta = dict(rec.meta)
    meta.setdefault("kind", rec.kind)
    prep = (kind.prepare or prepare)(kd, meta)
    stage("prepared")
    limit = int(kind.max_order_limit(prep))
    if max_order is not None and max_order > limit:
        raise input_error(
            f"{kd.where}: --max-order",
            f"got {max_order}; this record resolves orders up to {limit} "
            "(half the samples per revolution of its slowest-sampled run, and at most "
            f"{MAX_PARAM_FRACTION:.0%} of the fitted values as parameters)",
            f"a max order <= {limit}",
        )
    order = min(limit, kind.default_max_order) if max_order is None else max_order
    prep.consts["max_order"] = order  # type: ignore[index]
    base_spec, base_info = kind.base(prep, order)
    base_terms = [make_term(c, prep, st) for c, st in base_spec]
    for tm in base_terms:
        for q in tm.cand.params:
            if q.scale is None:
                tm.scale[q.name][...] = float(np.mean(prep.sigma))
    # a second bar moves through every chunked pass over the rows (fits, residuals)
    rows_bar = progress_bar("  pass", prep.n, enabled=verbose, unit="row")

    def chunk_done(a: int, b: int, n: int) -> None:
        if a == 0:
            rows_bar.reset(total=n)
        rows_bar.update(b - a)

    fitter = Fitter(prep, progress=chunk_done)
    cands = list(kind.candidates(prep.ctx)) + list(extra_candidates)
    seen: dict[str, Candidate] = {}
    for c in cands:
        seen[c.name] = c  # later ones (reference terms, user terms) override by name
    cands = list(seen.values())
    scan = _scan_order(limit, order)

    def log(msg: str) -> None:
        if verbose:
            bar.set_postfix_str(msg)

    # alignment: after the base fit, rotation-locked candidates see the aligned angle
    base_fit = fitter.fit(base_terms)
    refined = base_info["refine"](base_fit.terms, prep) if "refine" in base_info else None
    if refined:
        # the kind moved the angle its base model is evaluated at (e.g. the shaft from the
        # heads' mean less the fitted error's mean): refit from the fitted values
        base_info["refined"] = refined
        fitter.clear()
        base_fit = fitter.fit(base_fit.terms)

    def align(fit: FitResult) -> None:
        if "align" in base_info:
            aligned = base_info["align"](fit.terms, prep)
            if callable(aligned):  # a lazy column fn(lo, hi)
                prep.rows.set_lazy("theta", aligned)
            else:
                prep.rows["theta"] = aligned
            fitter.clear()

    align(base_fit)

    def estimate_noise(fit: FitResult) -> None:
        # the noise from the base residual's periodogram (structure cannot inflate it);
        # refit the weights with it
        r_base = fitter.residual(fit.terms)
        if kind.noise is not None and kind.noise_replaces:
            sig = np.asarray(kind.noise(prep, r_base), float)
        else:
            sig = noise_spectral(prep, r_base)
            if kind.noise is not None:  # the kind's second estimate: the smaller of the two
                sig = np.fmin(sig, np.asarray(kind.noise(prep, r_base), float))
        del r_base
        if np.all(np.isfinite(sig)) and np.all(sig > 0):
            prep.sigma = sig
            prep.ctx.noise[...] = sig
            fitter.w_ch = 1.0 / sig**2
            fitter.clear()

    estimate_noise(base_fit)
    for _ in range(2 if kind.grows_orders and max_order is None else 0):
        grown = _grow_base_order(kind, prep, fitter, base_fit, order, limit, base_info)
        if grown is None:
            break
        order, base_fit = grown
        scan = _scan_order(limit, order)
        align(base_fit)  # the refit moved the run offsets a little
        estimate_noise(base_fit)  # the orders it left out were in the residual
    stage("base fitted")
    sel = select(prep, fitter, base_fit.terms, cands, kind.views, scan, max_effects, log)
    stage("selected")
    base, final = sel["base"], sel["final"]
    C = prep.n_channels
    sig_mean = float(np.mean(prep.sigma))
    gof = goodness_of_fit(prep, sel["final_resid"], final.n_params)
    gof_base = sel["gof0"]
    stage("held-out + goodness of fit")
    effects = []
    for s in sel["accepted"]:
        idx = next(i for i, t in enumerate(final.terms) if t.cand.name == s.name)
        term = final.terms[idx]
        params = term_params(term, final, idx)
        derived = {}
        if term.cand.derived is not None:
            derived = term.cand.derived(prep.ctx, term.values, _se_dict(term, final, idx))
        chans = _significant_channels(term, final, idx, C, prep.ctx.n_runs)
        expl = term.cand.explanation
        effects.append(
            {
                "name": s.name,
                "params": params,
                "derived": derived,
                "channels": [kd.channel_names[k] for k in chans] if chans is not None else None,
                "rms_after": s.fit.rms(prep),
                "heldout_rms_after": s.fit.heldout_rms(prep),
                "delta_bic": float(s.delta_bic),
                "delta_heldout_chi2": float(s.delta_heldout),
                "collinearity": float(s.collinearity) if np.isfinite(s.collinearity) else None,
                "share": float(sel["shares"].get(s.name, 0.0)),
                "size_rms": float(s.term_rms * sig_mean),
                "notes": s.notes,
                "explanation": expl,
                "confounded_with": s.confounded,
            }
        )
    unexplained = [
        {**f.to_json(sig_mean), "note": "significant structure no named effect explains"}
        for f in sel["findings"][:12]
    ]
    if kind.reading_lattice and not any(e["name"] == "quantization" for e in effects):
        q_eff = lattice_effect(prep, final.rms(prep), final.heldout_rms(prep))
        if q_eff is not None:
            effects.append(q_eff)
    if effects:
        verdict = "missing_physics"
    elif unexplained or not gof["passes"]:
        verdict = "unexplained"
    else:
        verdict = "consistent"
    nuis_notes = []
    if prep.excluded:
        nuis_notes.append(
            f"{len(prep.excluded)} non-steady segment(s) left out of every fit "
            f"({sum(e['n_rows'] for e in prep.excluded)} rows)"
        )
    base_params = {t.cand.name: term_params(t, base, i) for i, t in enumerate(base.terms)}
    # the base terms as refitted with the named effects (kinds report e.g. their ellipse)
    final_base = {
        t.cand.name: term_params(t, final, i)
        for i, t in enumerate(final.terms)
        if t.cand.name in base_params
    }
    stage("report")
    doc = {
        "format": "encdesign-diagnosis/2",
        "kind": rec.kind,
        "recording": str(rec.path) if rec.path is not None else None,
        "verdict": verdict,
        "unit": kd.unit,
        "rms_before": base.rms(prep),
        "heldout_rms_before": base.heldout_rms(prep),
        "rms_final": final.rms(prep),
        "heldout_rms_final": final.heldout_rms(prep),
        "noise": {
            "per_channel": [float(s) for s in prep.sigma],
            "channels": kd.channel_names,
            "method": "median of the base residual's periodogram per channel (white noise: "
            "ln 2 sigma^2; structure in fewer than half the bins cannot inflate it); second "
            "differences for the first weights and the glitch scan",
        },
        "goodness_of_fit": gof,
        "goodness_of_fit_base": gof_base,
        "heldout": prep.fold_design,
        "excluded_segments": prep.excluded,
        "glitches": prep.glitches,
        "count_jumps": [
            {k: v for k, v in j.items() if k not in ("index", "channel_index")}
            for j in prep.count_jumps
        ],
        "gaps": prep.gaps,
        "effects": effects,
        "unexplained": unexplained,
        "rejected": sel["rejected"],
        "not_testable": sel["not_testable"],
        "findings_before": [f.to_json(sig_mean) for f in sel["findings0"][:12]],
        "base": {
            "terms": base_params,
            "max_order": order,
            "max_order_limit": limit,
            "max_param_fraction": MAX_PARAM_FRACTION,
            "n_params": base.n_params,
            "unidentifiable": base.unidentifiable + base_info.get("unidentifiable", []),
            "has_theta_ref": prep.ctx.has_ref,
            "terms_with_effects": final_base,
            **{
                k: v for k, v in base_info.items() if k not in ("align", "refine", "unidentifiable")
            },
        },
        "notes": nuis_notes,
        "status": "ok"
        if (base.converged and final.converged)
        else "a least-squares fit stopped before converging",
        "time_s": time.perf_counter() - t0,
    }
    doc["spectrum"] = order_spectrum(prep, sel["base_resid"], sel["final_resid"], scan)
    # issue 22 item 4 (call site): a record mostly excluded is said so, with the reasons
    from ._nuisances import excluded_share

    doc["excluded_share"] = excluded_share(prep.n, int(prep.keep.sum()), prep.excluded)
    if kind.summary is not None:
        doc.update(kind.summary(prep, base_params))
    doc["report"] = report_text(doc)
    rows_bar.close()
    bar.close()
    doc["_plot"] = dict(prep=prep, base_resid=sel["base_resid"], final_resid=sel["final_resid"])
    return doc


SWEEP_WINDOW = 9
"""Rows of the centred moving mean of :func:`_sweep_grid` (odd)."""
SWEEP_COHERENCE = 0.5
"""Above it, the moving mean's phase on the lattice is locked: a sampled sweep, not a
quantized reading."""


def _sweep_grid(v: np.ndarray, keep: np.ndarray, run: np.ndarray, lat) -> bool:
    """Whether a value lattice is only the time grid of a steady sweep.

    An evenly sampled steady sweep advances a fixed number of "steps" per sample: its values
    sit on a lattice without any quantizer (then the reading is not coarse, the sampling is).
    The tell is the unquantized signal: the centred moving mean over ``SWEEP_WINDOW`` rows of a
    quantized reading follows the signal between the levels (its phase ``u`` on the lattice
    spreads over the step, dithered or not), while that of a sampled sweep stays on the lattice
    (``|mean exp(2 pi i u)| > SWEEP_COHERENCE``)."""
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
    return n > 0 and abs(z) / n > SWEEP_COHERENCE


LATTICE_ROWS = 1 << 14
"""Rows of each run (from its start) that the value-lattice test of :func:`lattice_effect`
reads."""


def lattice_effect(prep: Prepared, rms_final: float, heldout_final: float | None) -> dict | None:
    """``quantization`` named from the value lattice of the readings, not fitted.

    Per channel, the readings of the kept rows (each run with its own zero) are tested for a
    lattice ``c_r + q k`` (``_reference_terms.detect_lsb``); a channel whose floor
    ``q^2 / 12`` is at least ``LATTICE_NOISE_SHARE`` of its measured noise variance (which,
    estimated from the data, includes the quantization) carries the effect. A dithered
    staircase (noise ahead of the quantizer above about ``q / 2``) leaves nothing for a
    model of the reading to fit: the finding is the LSB itself, so ``delta_bic``,
    ``collinearity`` and the held-out change are ``None`` (no parameter was fitted), and the
    residual RMS are the final model's. ``None`` when no channel qualifies."""
    from ._reference_terms import detect_lsb

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
        lat = detect_lsb(reading[keep, k], run[keep])
        if lat.lsb_rad is None or _sweep_grid(reading[:, k], keep, run, lat):
            continue
        sh = (lat.lsb_rad**2 / 12.0) / float(prep.sigma[k]) ** 2
        if sh >= LATTICE_NOISE_SHARE:
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
    the base and the final residual (least squares over the kept rows)."""

    M = int(min(max_order, 400))
    out = {"orders": list(range(1, M + 1)), "before": [], "after": []}
    N, _, _, _, sums = order_sums(prep, "theta", [r0, r1], np.arange(1, M + 1))
    for (Bc, Bs), key in zip(sums, ("before", "after")):
        a = 2 * Bc / max(N, 1)
        b = 2 * Bs / max(N, 1)
        out[key] = [float(v) for v in np.mean(np.hypot(a, b), axis=1)]
    return out


def _significant_channels(term: Term, fit: FitResult, idx: int, C: int, R: int):
    """Channels whose per-channel parameters differ from zero by more than 3 se (``None``
    when the term has no per-channel parameter)."""
    se = _se_dict(term, fit, idx)
    per = [q for q in term.cand.params if q.shape in ("channels", "runs*channels")]
    if not per or C == 1:
        return None
    z = np.zeros(C)
    for q in per:
        v = np.abs(term.values[q.name]) / np.where(se[q.name] > 0, se[q.name], np.inf)
        v = np.nan_to_num(v)
        z = np.maximum(z, v.reshape(-1, C).max(0))
    return [k for k in range(C) if z[k] > 3]


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
    if doc.get("excluded_share"):  # issue 22 item 4 (call site): prominent, near the top
        lines.insert(2, "WARNING: " + doc["excluded_share"]["note"])
    for e in doc["excluded_segments"]:
        lines.append(
            f"excluded: run {e['run']} t {e['t_start_s']:.4g}..{e['t_end_s']:.4g} s "
            f"({e['n_rows']} rows): {e['reason']}"
        )
    for gl in doc["glitches"]:
        lines.append(f"glitch: run {gl['run']} t {gl['t_s']:.6g} s channel {gl['channel']}")
    for j in doc["count_jumps"]:
        lines.append(
            f"count jump: run {j['run']} t {j['t_s']:.6g} s channel {j['channel']} "
            f"size {j['size']:.4g} {u}"
        )
    for gp in doc["gaps"]:
        lines.append(f"gap: run {gp['run']} at t {gp['t_s']:.6g} s for {gp['duration_s']:.3g} s")
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
        lines.append(f"  {e['explanation']}")
        for n in e["notes"]:
            lines.append(f"  note: {n}")
    for r in doc["rejected"]:
        lines.append(f"rejected {r['name']}: {r['reason']}")
    for r in doc["not_testable"]:
        lines.append(f"not testable {r['name']}: {r['reason']}")
    for x in doc["unexplained"]:
        w = x["where"]
        loc = ", ".join(f"{k} {[round(v, 4) for v in w[k]][:6]}" for k in w if w[k])
        lines.append(f"unexplained ({x['view']}): {loc}; rms {x['rms']:.4g} {u}")
    lines.append(f"status: {doc['status']}; {doc['time_s']:.1f} s")
    return "\n".join(lines) + "\n"
