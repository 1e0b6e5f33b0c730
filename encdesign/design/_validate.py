"""Out-of-sample validation of Monte Carlo optima: the chosen design against its baseline on
fresh builds.

An optimum of a sample average over a fixed set of builds overfits that set: on the
training builds it looks better than on any other. Every driver that claims a Monte Carlo
win re-evaluates the chosen design **and** the baseline it is compared with on builds drawn
from keys independent of the training key (:func:`fresh_key`, :func:`fresh_seeds`), the
same fresh builds for both (common random numbers: the paired difference has a far smaller
standard error than either figure). :func:`paired_comparison` turns the paired fresh values
into the report: both figures with standard errors, the difference with its standard error,
and ``win_significant`` (the chosen design is better by more than ``z`` standard errors of
the difference; ``z = 2`` by default, about 97.7 % one-sided).

Two kinds of paired sample:

* per-build values (``n`` fresh builds of one fresh key), summarised by their mean, or by
  the root of their mean (``reduce="rms"``, for mean squares; the standard errors then come
  from the delta method);
* per-replicate values (``R`` independent fresh replicates of the whole estimator, e.g. a
  percentile over ``n`` builds; :func:`validate_problem`), summarised by their mean.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np
from jaxtyping import ArrayLike

from .._errors import input_error

Z_SIGNIFICANT = 2.0
"""Default number of standard errors of the paired difference that make a win significant."""

FRESH_TAG = 27_270_027
"""Folded into a training key (or seed) to make the fresh keys: never a training key."""


def fresh_key(key: jax.Array, index: int = 0) -> jax.Array:
    """A key for fresh builds, independent of the builds of ``key`` (and of
    ``fresh_key(key, j)`` for ``j != index``): ``fold_in(fold_in(key, FRESH_TAG), index)``.

    Training builds are ``fold_in(key, i)`` for build indices ``i``; the fresh key is a
    different branch of the key tree, so no fresh build repeats a training build."""
    return jax.random.fold_in(jax.random.fold_in(key, FRESH_TAG), int(index))


def fresh_seeds(seed: int, n: int) -> list[int]:
    """``n`` integer seeds (``0 … 2^63 - 1``) independent of ``seed`` and of each other, for
    objectives that build their key from a seed (:class:`~encdesign.Problem`)."""
    ss = np.random.SeedSequence([int(seed), FRESH_TAG])
    return [int(s) >> 1 for s in ss.generate_state(max(int(n), 0), np.uint64)]


@dataclasses.dataclass(frozen=True)
class FreshComparison:
    """Chosen design against baseline on the same fresh builds (lower is better).

    Attributes:
        chosen, chosen_stderr: the chosen design's figure on the fresh sample, and its
            standard error (units of the values).
        baseline, baseline_stderr: the same for the baseline.
        difference, difference_stderr: ``baseline - chosen`` (positive: the chosen design
            is better) and the standard error of the paired difference.
        z: ``difference / difference_stderr`` (``inf`` when the difference is exact).
        win_significant: ``difference > z_threshold * difference_stderr``.
        worse_significant: ``difference < -z_threshold * difference_stderr``.
        ratio: ``baseline / chosen`` (the "improvement" on fresh builds).
        n: paired sample size (builds, or replicates).
        unit: ``"builds"`` or ``"replicates"``.
        reduce: ``"mean"`` or ``"rms"``.
        z_threshold: the threshold used.
        verdict: ``"win"``, ``"loss"`` or ``"no significant difference"``.
    """

    chosen: float
    chosen_stderr: float
    baseline: float
    baseline_stderr: float
    difference: float
    difference_stderr: float
    z: float
    win_significant: bool
    worse_significant: bool
    ratio: float
    n: int
    unit: str
    reduce: str
    z_threshold: float

    @property
    def verdict(self) -> str:
        """``"win"``, ``"loss"`` or ``"no significant difference"``."""
        if self.win_significant:
            return "win"
        return "loss" if self.worse_significant else "no significant difference"

    def as_dict(self) -> dict[str, float | int | bool | str | None]:
        """JSON-able (non-finite numbers as ``None``)."""
        d = dataclasses.asdict(self)
        d["verdict"] = self.verdict
        return {
            k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()
        }

    def describe(self, units: str = "", scale: float = 1.0) -> str:
        """One line: both figures, the difference and the verdict (values times ``scale``)."""
        u = f" {units}" if units else ""
        return (
            f"fresh ({self.n} {self.unit}): chosen {self.chosen * scale:.4g} +- "
            f"{self.chosen_stderr * scale:.2g}{u}, baseline {self.baseline * scale:.4g} +- "
            f"{self.baseline_stderr * scale:.2g}{u}, baseline - chosen "
            f"{self.difference * scale:.3g} +- {self.difference_stderr * scale:.2g}{u} "
            f"(z {self.z:.2f}): {self.verdict}"
        )


def paired_comparison(
    chosen_values: ArrayLike,
    baseline_values: ArrayLike,
    *,
    reduce: str = "mean",
    unit: str = "builds",
    z_threshold: float = Z_SIGNIFICANT,
) -> FreshComparison:
    """Compare two designs on the same fresh sample (common random numbers), lower better.

    Args:
        chosen_values, baseline_values: paired values ``[n]`` (entry ``i`` of both from the
            same fresh build or replicate), any units; ``n >= 2``.
        reduce: ``"mean"`` (the figure is the sample mean) or ``"rms"`` (the values are
            mean squares and the figure is ``sqrt(mean)``; standard errors by the delta
            method, the difference's from the paired linearised values).
        unit: what a sample entry is (``"builds"`` or ``"replicates"``), for the report.
        z_threshold: standard errors of the difference for a significant win (> 0).

    Raises:
        EncdesignInputError: mismatched shapes, fewer than two entries, non-finite values,
            an unknown ``reduce`` or a threshold <= 0.
    """
    a = np.asarray(chosen_values, dtype=np.float64).reshape(-1)
    b = np.asarray(baseline_values, dtype=np.float64).reshape(-1)
    if a.shape != b.shape or a.size < 2:
        raise input_error(
            "paired_comparison", f"{a.size} and {b.size} values", "two equal samples of >= 2"
        )
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise input_error("paired_comparison", "non-finite fresh values", "finite values")
    if reduce not in ("mean", "rms"):
        raise input_error("paired_comparison.reduce", f"{reduce!r}", "'mean' or 'rms'")
    if not z_threshold > 0:
        raise input_error("paired_comparison.z_threshold", f"{z_threshold!r}", "> 0")
    n = a.size
    ma, mb = float(np.mean(a)), float(np.mean(b))
    if reduce == "mean":
        fa, fb = ma, mb
        la, lb = a, b
    else:
        if ma <= 0 or mb <= 0:
            raise input_error("paired_comparison", "mean square <= 0 with reduce='rms'", "> 0")
        fa, fb = math.sqrt(ma), math.sqrt(mb)
        la, lb = a / (2.0 * fa), b / (2.0 * fb)  # linearised: d sqrt(m) = dm / (2 sqrt m)
    se_a = float(np.std(la, ddof=1)) / math.sqrt(n)
    se_b = float(np.std(lb, ddof=1)) / math.sqrt(n)
    se_d = float(np.std(lb - la, ddof=1)) / math.sqrt(n)
    d = fb - fa
    z = d / se_d if se_d > 0 else (math.inf if d > 0 else (-math.inf if d < 0 else 0.0))
    return FreshComparison(
        chosen=fa,
        chosen_stderr=se_a,
        baseline=fb,
        baseline_stderr=se_b,
        difference=d,
        difference_stderr=se_d,
        z=float(z),
        win_significant=bool(z > z_threshold),
        worse_significant=bool(z < -z_threshold),
        ratio=fb / fa if fa != 0 else math.inf,
        n=n,
        unit=unit,
        reduce=reduce,
        z_threshold=float(z_threshold),
    )
