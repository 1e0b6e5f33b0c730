"""The value lattice of a column of readings (NumPy, not traced): :func:`detect_lsb`, the LSB of
a quantized reading and each run's offset on it. The engine names ``quantization`` from it
(:func:`~encdesign.diagnose.engine._document.lattice_effect`) for every kind whose channels
are angle readings; the sensor-against-reference candidates test on it too.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._settings import FinderSettings

__all__ = ["Lattice", "detect_lsb"]


@dataclasses.dataclass(frozen=True)
class Lattice:
    """Result of :func:`detect_lsb`.

    Attributes:
        lsb_rad: the lattice step ``q`` (rad), or ``None`` when the values lie on no lattice.
        offset_rad: per-run lattice offsets ``c_r`` in ``[0, q)`` (rad), run id -> offset.
        fraction_on_lattice: share of values within ``tolerance * q`` of ``c_r + q k``.
        counts_per_turn: ``2 pi / q`` (levels per turn), ``None`` without a lattice.
        bits_per_turn: ``log2(2 pi / q)``, ``None`` without a lattice.
        n_levels: number of distinct lattice levels seen.
        single_step: every consecutive difference is one step (a stepped sweep, not
            necessarily a quantized reading).
        note: how it was decided.
    """

    lsb_rad: float | None
    offset_rad: dict[int, float]
    fraction_on_lattice: float
    counts_per_turn: float | None
    bits_per_turn: float | None
    n_levels: int
    single_step: bool
    note: str

    def as_dict(self) -> dict:
        """JSON-ready dict."""
        d = dataclasses.asdict(self)
        d["offset_rad"] = {str(k): v for k, v in self.offset_rad.items()}
        return d


def _unique_sorted(v: np.ndarray, eps: float) -> np.ndarray:
    u = np.unique(v)
    if u.size < 2:
        return u
    keep = np.concatenate([[True], np.diff(u) > eps])
    return u[keep]


def _approximate_gcd(x: np.ndarray, tol: float, max_iter: int = 200) -> float | None:
    """Largest ``g`` of which every ``x`` is an integer multiple within ``tol`` (Euclid)."""
    S = np.unique(x[x > tol])
    for _ in range(max_iter):
        if S.size == 0:
            return None
        g = float(S[0])
        r = np.mod(S, g)
        r = np.minimum(r, g - r)
        r = r[r > tol]
        if r.size == 0:
            return g
        S = np.unique(np.concatenate([[g], r]))
    return None


def detect_lsb(
    values_rad: np.ndarray,
    run: np.ndarray | None = None,
    *,
    settings: FinderSettings,
) -> Lattice:
    """Find the step of the value lattice of a quantized reading (rad).

    Values of one run lie on ``c_r + q k`` (integers ``k``; each run may have its own zero
    ``c_r``). The smallest gap ``d_min`` between distinct values of a run is ``q`` or a multiple
    of it: the step is the largest ``d_min / j`` (``j = 1 … lattice_max_divisor``) of which at
    least ``lattice_min_fraction`` of all gaps are integer multiples within
    ``lattice_tolerance * q`` (values printed with a few digits pass). When that fails, or finds
    only an even sweep,
    readings computed from integer counts still sit on their lattice to rounding error: the step
    is then the approximate greatest common divisor of the gaps (Euclid's algorithm with an
    absolute tolerance of ``1e-12`` of the largest value), even when every gap is hundreds of
    steps (a fast sweep); a "step" not over ``lattice_exact_floor`` times that tolerance
    (continuous values) or over ``lattice_gap_steps_max`` times below the typical gap (a file's
    printed decimals) is refused. Either step is refined by least squares over the gaps. A
    record without a lattice (continuous values) fails the first test: the fractional parts of
    its gaps are spread uniformly, so only about ``2 lattice_tolerance`` of them pass. Values
    that step evenly by one gap and never repeat are a uniform sweep sampled evenly, not a
    quantized reading: no lattice.

    Args:
        values_rad: the readings, rad (any unwrapped angle).
        run: run id per value (``None``: one run).
        settings: the finder's thresholds; the ``lattice_*`` fields decide (tolerance in
            steps, largest divisor, least share of gaps and values on the lattice, least
            number of gaps, the exact branch's floor and largest gap in steps).

    Returns:
        A :class:`Lattice`.
    """
    tolerance = settings.lattice_tolerance
    max_divisor = settings.lattice_max_divisor
    min_fraction = settings.lattice_min_fraction
    min_differences = settings.lattice_min_differences
    v = np.asarray(values_rad, dtype=np.float64)
    run = np.zeros(v.size, dtype=np.int64) if run is None else np.asarray(run)
    scale = float(np.max(np.abs(v))) if v.size else 0.0
    eps = 64.0 * np.finfo(np.float64).eps * max(scale, 1.0)
    gaps = []
    for r in np.unique(run):
        u = _unique_sorted(v[run == r], eps)
        if u.size >= 2:
            gaps.append(np.diff(u))
    none = Lattice(None, {}, 0.0, None, None, 0, False, "")
    if not gaps or sum(g.size for g in gaps) < min_differences:
        return dataclasses.replace(
            none, note=f"fewer than {min_differences} distinct gaps between values: no decision"
        )
    d = np.concatenate(gaps)
    d_min = float(d.min())
    q = None
    # 1) a lattice seen through rounded numbers (printed with a few digits): the largest
    #    d_min / j of which the gaps are multiples within ``tolerance`` steps
    for j in range(1, max_divisor + 1):
        cand = d_min / j
        r = d / cand
        if np.mean(np.abs(r - np.round(r)) <= tolerance) >= min_fraction:
            q = cand
            break
    repeats = int(v.size) - sum(g.size + 1 for g in gaps)
    even = q is not None and bool(np.all(np.round(d / q) == 1)) and repeats == 0
    if q is None or even:
        # 2) an exact lattice (readings computed from integer counts): Euclid's algorithm on
        #    the gaps with an absolute tolerance finds a step far below the smallest gap (a
        #    fast sweep whose gaps are all ~250 LSB). Continuous values only reach a "step"
        #    of the size of the tolerance; a step over lattice_gap_steps_max times below the
        #    typical gap (the decimal digits a file was printed with) is not a reading's
        #    resolution either
        exact_tol = 1e-12 * max(scale, 1.0)
        g = _approximate_gcd(d, exact_tol)
        if (
            g is not None
            and g > settings.lattice_exact_floor * exact_tol
            and np.median(d) / g <= settings.lattice_gap_steps_max
        ):
            q, tolerance = g, 10 * exact_tol / g  # tolerance in steps
    if q is None:
        return dataclasses.replace(
            none,
            note=f"gaps are not integer multiples of d_min/j (j <= {max_divisor}): no lattice",
        )
    k = np.round(d / q)
    ok = (np.abs(d / q - k) <= tolerance) & (k > 0)
    if not np.any(ok):
        # (Euclid's step of an evenly sampled sweep with a few wider gaps: no gap within the
        # exact tolerance of a multiple of it, so no step to refine; session 40, a clean
        # multihead record's reference crashed here on 0 / 0)
        return dataclasses.replace(
            none, note=f"no gap is a whole multiple of the step {q:.6g} rad found: no lattice"
        )
    q = float(np.sum(k[ok] * d[ok]) / np.sum(k[ok] ** 2))
    offsets: dict[int, float] = {}
    on = np.zeros(v.size, dtype=bool)
    levels = set()
    for r in np.unique(run):
        m = run == r
        ph = np.mod(v[m], q) / q * 2.0 * np.pi
        c = float(np.mod(np.angle(np.mean(np.exp(1j * ph))) / (2 * np.pi), 1.0) * q)
        kk = np.round((v[m] - c) / q)
        on[m] = np.abs((v[m] - c) / q - kk) <= tolerance
        levels.update((int(r), int(x)) for x in kk)
        offsets[int(r)] = c
    frac = float(np.mean(on))
    if frac < min_fraction:
        return dataclasses.replace(
            none,
            fraction_on_lattice=frac,
            note=f"gaps fit a step of {q:.6g} rad but only {frac:.1%} of the values do",
        )
    single = bool(np.all(np.round(d / q) == 1))
    repeats = int(v.size) - sum(g.size + 1 for g in gaps)
    if single and repeats == 0:
        return dataclasses.replace(
            none,
            fraction_on_lattice=frac,
            single_step=True,
            note=(
                f"consecutive values step evenly by {q:.6g} rad and none repeats: a uniform "
                "sweep sampled evenly, not a quantized reading"
            ),
        )
    cpt = 2.0 * np.pi / q
    return Lattice(
        lsb_rad=q,
        offset_rad=offsets,
        fraction_on_lattice=frac,
        counts_per_turn=float(cpt),
        bits_per_turn=float(math.log2(cpt)),
        n_levels=len(levels),
        single_step=single,
        note=(
            f"{d.size} gaps between distinct values are integer multiples of {q:.6g} rad "
            f"(smallest gap / {int(round(d_min / q))}); {frac:.1%} of the values on the lattice"
        ),
    )
