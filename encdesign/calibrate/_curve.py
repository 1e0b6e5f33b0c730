"""Calibration curves: a best-fit low-order trigonometric sum, its order chosen by held-out
error, its uncertainty band, and the correction table it writes (seed ``001_…``, claim 11,
figs. 19–20 and 23: "a best fit low order trigonometric sum as a calibration curve").

The curve is ``c(θ) = a_0 + Σ_{k=1}^{K} a_k cos kθ + b_k sin kθ`` fitted by (weighted)
least squares to error samples ``y_i`` at angles ``θ_i`` (rad). The order ``K`` is chosen by
cross-validation: the samples are split into ``n_folds`` interleaved angular blocks, each
order is fitted on all blocks but one and scored on the one left out; the chosen order is
the smallest whose mean held-out mean-square error is within one standard error (over
the folds) of the best (the one-standard-error rule). Inside the folds the samples are
weighted by the diagonal of the input covariance (correlations are used only in the final
fit). The band is the standard error of
``c(θ)`` from the coefficient covariance: the input covariance propagated through the fit
(a closure result's ``covariance_rad2``) or, without one, the residual scatter; in both
cases inflated by ``max(1, χ²/dof)`` so that a misfit widens it.

Correction: ``corrected = reading − c(reading)``. The correction table
(:func:`write_correction_table`, format in ``docs/calibration.md``) is a CSV with columns
``angle_rad, correction_rad, correction_se_rad`` at equally spaced angles in ``[0, 2π)``;
:func:`apply_correction_table` interpolates it periodically.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from .._errors import input_error

__all__ = [
    "CalibrationCurve",
    "apply_correction_table",
    "fit_curve",
    "read_correction_table",
    "write_correction_table",
]

TABLE_COLUMNS = ("angle_rad", "correction_rad", "correction_se_rad")


def _design(theta: np.ndarray, order: int) -> np.ndarray:
    cols = [np.ones_like(theta)]
    for k in range(1, order + 1):
        cols += [np.cos(k * theta), np.sin(k * theta)]
    return np.stack(cols, axis=-1)


@dataclasses.dataclass(frozen=True)
class CalibrationCurve:
    """A fitted calibration curve (rad).

    Attributes:
        status: ``"ok"``.
        order: the chosen order K.
        coef_rad: ``(a_0, a_1, b_1, …, a_K, b_K)``, rad.
        covariance_rad2: their covariance, rad².
        orders_tried: the orders scored.
        heldout_rms_rad: held-out RMS of each order tried (same order as ``orders_tried``).
        heldout_se_rad: standard error over folds of each order's held-out mean square,
            expressed as an RMS step (``se / (2 rms)``), rad.
        fitted_rms_rad: RMS residual of the chosen fit on all samples, rad.
        chi2, dof: weighted residual sum of squares of the chosen fit and its degrees of
            freedom (meaningful when an input covariance was given).
        inflation: ``max(1, χ²/dof)`` applied to the covariance.
    """

    status: str
    order: int
    coef_rad: np.ndarray
    covariance_rad2: np.ndarray
    orders_tried: list[int]
    heldout_rms_rad: list[float]
    heldout_se_rad: list[float]
    fitted_rms_rad: float
    chi2: float
    dof: int
    inflation: float

    def __call__(self, theta_rad: np.ndarray) -> np.ndarray:
        """``c(θ)``, rad."""
        th = np.asarray(theta_rad, dtype=float)
        return _design(th, self.order) @ self.coef_rad

    def band_rad(self, theta_rad: np.ndarray) -> np.ndarray:
        """Standard error of ``c(θ)``, rad."""
        x = _design(np.asarray(theta_rad, dtype=float), self.order)
        v = np.einsum("...i,ij,...j->...", x, self.covariance_rad2, x)
        return np.sqrt(np.clip(v, 0.0, None))

    def correct(self, reading_rad: np.ndarray) -> np.ndarray:
        """``reading − c(reading)``, rad (the curve evaluated at the reading itself)."""
        r = np.asarray(reading_rad, dtype=float)
        return r - self(r)

    def amplitudes_rad(self) -> np.ndarray:
        """Amplitude ``hypot(a_k, b_k)`` of orders ``1 … K``, rad."""
        c = self.coef_rad[1:].reshape(-1, 2)
        return np.hypot(c[:, 0], c[:, 1])


def _fit(x, y, w_sqrt_inv):
    """Least squares with a whitening operator (None: unweighted)."""
    if w_sqrt_inv is None:
        xw, yw = x, y
    else:
        xw, yw = w_sqrt_inv @ x, w_sqrt_inv @ y
    coef, *_ = np.linalg.lstsq(xw, yw, rcond=None)
    return coef, xw, yw


def fit_curve(
    theta_rad: np.ndarray,
    error_rad: np.ndarray,
    *,
    covariance_rad2: np.ndarray | None = None,
    max_order: int | None = None,
    order: int | None = None,
    n_folds: int = 4,
) -> CalibrationCurve:
    """Fit a calibration curve to error samples and choose its order by held-out error.

    Args:
        theta_rad: angles of the samples, rad, ``(n,)``.
        error_rad: errors there (reading − true), rad, ``(n,)``.
        covariance_rad2: covariance of the errors, ``(n, n)`` rad² (e.g. a closure
            result's instrument block); ``None``: independent errors of equal, unknown
            size (estimated from the residual).
        max_order: highest order tried (default: the most the folds allow, at most 12).
        order: use this order instead of choosing one (cross-validation still reported).
        n_folds: interleaved angular blocks for the held-out error (>= 2).

    Returns:
        :class:`CalibrationCurve`.

    Raises:
        EncdesignInputError: shapes, non-finite values, too few samples for any order.
    """
    th = np.asarray(theta_rad, dtype=float).reshape(-1)
    y = np.asarray(error_rad, dtype=float).reshape(-1)
    if th.shape != y.shape or th.size < 4:
        raise input_error(
            "fit_curve", f"{th.size} angles, {y.size} errors", "two equal 1-D arrays, >= 4"
        )
    if not (np.all(np.isfinite(th)) and np.all(np.isfinite(y))):
        raise input_error("fit_curve", "non-finite angle or error", "finite samples")
    if isinstance(n_folds, bool) or not isinstance(n_folds, int) or n_folds < 2:
        raise input_error("fit_curve n_folds", f"got {n_folds!r}", "an integer >= 2")
    n = th.size
    chol_inv = None
    if covariance_rad2 is not None:
        c = np.asarray(covariance_rad2, dtype=float)
        if c.shape != (n, n) or not np.all(np.isfinite(c)):
            raise input_error("fit_curve covariance_rad2", f"shape {c.shape}", f"({n}, {n})")
        # closure covariances are singular along the constant (Σe = 0): regularise there
        c = c + np.eye(n) * 1e-9 * max(float(np.trace(c)) / n, 1e-300)
        ell = np.linalg.cholesky(c)
        chol_inv = np.linalg.inv(ell)
    tm = np.mod(th, 2 * np.pi)
    n_blocks = max(n_folds, min(n, 8 * n_folds))
    fold = np.floor(tm / (2 * np.pi) * n_blocks).astype(int) % n_folds
    n_train_min = min(int(np.sum(fold != f)) for f in range(n_folds))
    k_cap = (n_train_min - 2) // 2
    if k_cap < 0:
        raise input_error(
            "fit_curve", f"{n} samples in {n_folds} folds", "enough samples for order 0"
        )
    for key, val in (("max_order", max_order), ("order", order)):
        if val is not None and (isinstance(val, bool) or not isinstance(val, int) or val < 0):
            raise input_error(key, f"got {val!r}", "an integer >= 0")
    if order is not None and order > k_cap:
        raise input_error(
            "order",
            f"{order} is above {k_cap}, the highest order {n} samples in {n_folds} folds resolve",
            f"0 <= order <= {k_cap}",
        )
    if max_order is None:
        max_order = min(12, k_cap)
    max_order = min(int(max_order), k_cap)
    orders = list(range(0, max_order + 1))
    sd = None
    if covariance_rad2 is not None:
        sd = np.sqrt(np.clip(np.diag(np.asarray(covariance_rad2, dtype=float)), 1e-300, None))
    mse_mean, mse_se = [], []
    for k in orders:
        per_fold = []
        for f in range(n_folds):
            tr, te = fold != f, fold == f
            if not te.any():
                continue
            x = _design(tm[tr], k)
            w = None
            if sd is not None:  # diagonal weights inside the folds
                w = np.diag(1.0 / sd[tr])
            coef, *_ = _fit(x, y[tr], w)
            res = y[te] - _design(tm[te], k) @ coef
            per_fold.append(float(np.mean(res**2)))
        pf = np.asarray(per_fold)
        mse_mean.append(float(pf.mean()))
        mse_se.append(float(pf.std(ddof=1) / math.sqrt(pf.size)) if pf.size > 1 else 0.0)
    best = int(np.argmin(mse_mean))
    if order is None:
        limit = mse_mean[best] + mse_se[best]
        chosen = next(k for k, m in zip(orders, mse_mean) if m <= limit)
    else:
        chosen = int(order)
    x = _design(tm, chosen)
    coef, xw, yw = _fit(x, y, chol_inv)
    resid_w = yw - xw @ coef
    dof = n - x.shape[1]
    chi2 = float(resid_w @ resid_w)
    xtx_inv = np.linalg.pinv(xw.T @ xw)
    if covariance_rad2 is None:
        s2 = chi2 / dof if dof > 0 else 0.0
        cov = s2 * xtx_inv
        inflation = 1.0
    else:
        inflation = max(1.0, chi2 / dof) if dof > 0 else 1.0
        cov = inflation * xtx_inv
    resid = y - x @ coef
    rms = [math.sqrt(m) for m in mse_mean]
    se_rms = [s / (2 * r) if r > 0 else 0.0 for s, r in zip(mse_se, rms)]
    return CalibrationCurve(
        status="ok",
        order=chosen,
        coef_rad=coef,
        covariance_rad2=cov,
        orders_tried=orders,
        heldout_rms_rad=rms,
        heldout_se_rad=se_rms,
        fitted_rms_rad=float(np.sqrt(np.mean(resid**2))),
        chi2=chi2,
        dof=int(dof),
        inflation=float(inflation),
    )


def write_correction_table(
    path: str | os.PathLike, curve: CalibrationCurve, n_points: int = 3600
) -> Path:
    """Write the correction table (``docs/calibration.md``) atomically; returns the path."""
    if isinstance(n_points, bool) or not isinstance(n_points, int) or n_points < 4:
        raise input_error("write_correction_table n_points", f"got {n_points!r}", ">= 4")
    path = Path(path)
    th = 2 * np.pi * np.arange(n_points) / n_points
    c, se = curve(th), curve.band_rad(th)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".csv")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(TABLE_COLUMNS)
            for row in zip(th, c, se):
                w.writerow([repr(float(v)) for v in row])
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def read_correction_table(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a correction table: ``(angle_rad, correction_rad, correction_se_rad)``.

    Raises:
        EncdesignInputError: missing file, wrong header, non-finite values, angles not
            equally spaced in ``[0, 2π)``.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise input_error(where, "file not found")
    with open(path, encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or tuple(h.strip() for h in rows[0]) != TABLE_COLUMNS:
        raise input_error(where, f"header {rows[0] if rows else []}", f"{list(TABLE_COLUMNS)}")
    try:
        a = np.asarray([[float(v) for v in r] for r in rows[1:] if r], dtype=float)
    except ValueError as exc:
        raise input_error(where, f"not a number ({exc})", "numbers") from None
    if a.ndim != 2 or a.shape[0] < 4 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise input_error(where, "fewer than 4 rows or non-finite values", "finite rows")
    th = a[:, 0]
    step = 2 * np.pi / th.size
    if np.max(np.abs(th - step * np.arange(th.size))) > 1e-9:
        raise input_error(where, "angles not equally spaced from 0", "k·2π/n, k = 0 … n−1")
    return th, a[:, 1], a[:, 2]


def apply_correction_table(
    table: tuple[np.ndarray, np.ndarray, np.ndarray], reading_rad: np.ndarray
) -> np.ndarray:
    """``reading − c(reading)`` with ``c`` interpolated linearly and periodically, rad."""
    th, c, _ = table
    r = np.asarray(reading_rad, dtype=float)
    xp = np.append(th, 2 * np.pi)
    fp = np.append(c, c[0])
    return r - np.interp(np.mod(r, 2 * np.pi), xp, fp)


def curve_from_closure(result, **kw) -> CalibrationCurve:
    """:func:`fit_curve` to a dual-closure result's instrument errors, with their
    covariance (keywords go to :func:`fit_curve`)."""
    n = result.n_faces
    return fit_curve(
        result.positions_rad,
        result.instrument_error_rad,
        covariance_rad2=result.covariance_rad2[:n, :n],
        **kw,
    )


def curve_from_recording(rec, **kw) -> tuple[CalibrationCurve, np.ndarray, np.ndarray, str]:
    """Fit a calibration curve to a recording.

    * ``closure``: the solved instrument errors (:func:`curve_from_closure`);
    * ``multihead`` with ``theta_ref``: the average of the symmetric heads (all heads but
      ``reference_head``) minus ``theta_ref``, against ``theta_ref``.

    Returns:
        ``(curve, theta_rad, error_rad, source)``: the samples fitted and a description.
    """
    where = str(rec.path) if rec.path is not None else "recording"
    if rec.kind == "closure":
        from ._closure import closure_from_recording

        res = closure_from_recording(rec)
        curve = curve_from_closure(res, **kw)
        return curve, res.positions_rad, res.instrument_error_rad, "closure instrument errors"
    if rec.kind == "multihead":
        if "theta_ref" not in rec.columns:
            raise input_error(where, "no theta_ref column", "a reference angle (theta_ref)")
        heads = rec.heads()
        ref = rec.encoder.get("reference_head")
        sym = [k for k in range(heads.shape[1]) if k != ref]
        th = np.asarray(rec.columns["theta_ref"], dtype=float)
        err = heads[:, sym].mean(axis=1) - th
        curve = fit_curve(th, err, **kw)
        return curve, th, err, f"mean of heads {sym} minus theta_ref"
    raise input_error(where, f"kind {rec.kind!r}", "a closure or multihead recording")
