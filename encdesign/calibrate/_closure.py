"""Dual-closure calibration of an angle instrument and an N-sided polygon (seed ``001_…``,
"full circle accuracy", figs. 16–24).

The polygon sits on the instrument's platform. At each *setting* ``s`` its face 0 is fixed
at instrument position ``p_s`` (in steps of ``2π/N``); the platform is then turned so that
faces ``0, 1, …, N−1`` and finally face 0 again are nulled on an autocollimator, giving
``N + 1`` readings ``r_{s,0…N}``. With ``q = (p_s + j) mod N`` the instrument position of
face ``j`` (``j = N`` is face 0 again), the reading minus its nominal angle is

    m_{s,j} = r_{s,j} − 2π q/N  (unwrapped) = e_q + f_j + c_s + noise,

with ``e_q`` the instrument's error at position ``q`` (reading minus true angle), ``f_j``
the error of face ``j`` (how much further than nominal the platform has to turn to null
it) and ``c_s`` the unknown angle at which the polygon was set down. The seed's system
takes the ``N`` differences of successive readings of each setting, which remove
``c_s``:

    m_{s,j+1} − m_{s,j} = e_{q(j+1)} − e_{q(j)} + f_{(j+1) mod N} − f_j,   j = 0 … N−1,

and adds the two closure conditions ``Σ_q e_q = 0`` and ``Σ_j f_j = 0`` (the differences
around the full circle sum to 360° for both devices). ``S`` settings give ``S(N+1)``
measurements, ``S·N + 2`` equations and ``2N`` unknowns: a complete test (``S = N``) is
``N(N+1)`` measurements and ``N² + 2`` equations (seed: N = 12 → 156, 146, 24).

Least squares. Successive differences share a reading, so with white reading noise of
standard deviation σ the ``N`` differences of one setting have covariance ``σ² T``,
``T = D Dᵀ`` (2 on the diagonal, −1 beside it). :func:`solve_closure` whitens each
setting's differences with the Cholesky factor of ``T`` (generalised least squares: the
best linear unbiased estimate; ``weighting="ols"`` solves the raw differences as the
seed wrote them, with sandwich standard errors), solves with
``scipy.linalg.lstsq`` and estimates σ from the whitened residual,
``σ̂² = RSS / (S·N − rank + 2)``. Standard errors are ``σ̂ √diag((AᵀA)⁺)``.

Harmonics. In the Fourier basis of the positions, harmonic ``k`` of ``Δe`` reaches each
setting multiplied by ``exp(2πi k p_s/N)``, while ``Δf`` does not move. Two settings
whose positions differ by ``d`` separate harmonic ``k`` unless ``k·d ≡ 0 (mod N)``. A
harmonic for which every pair of settings has ``k (p_s − p_{s'}) ≡ 0 (mod N)`` is
*undetermined*: only the sum of the instrument's and the polygon's harmonic is measured.
Each undetermined harmonic ``k`` with ``2k ≠ N`` costs the rank 2 (cos and sin), the
Nyquist harmonic 1. :func:`undetermined_harmonics` lists them; a system with any is
rank-deficient, and :func:`solve_closure` refuses it (``throw=True``) or returns the
minimum-norm solution flagged ``status = "rank_deficient"``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import cast

import numpy as np
import scipy.linalg

from .._errors import EncdesignInputError, input_error

__all__ = [
    "ClosureCounts",
    "ClosureResult",
    "closure_counts",
    "closure_from_recording",
    "closure_matrix",
    "closure_null_angles",
    "harmonic_amplitudes",
    "solve_closure",
    "undetermined_harmonics",
]


@dataclasses.dataclass(frozen=True)
class ClosureCounts:
    """Size of a dual-closure system (seed: "N(N+1) measurements … N²+2 equations in 2N
    unknowns" for a complete test).

    Attributes:
        n_faces: polygon faces N.
        n_settings: settings S.
        n_measurements: readings ``S (N + 1)``.
        n_equations: ``S·N`` differences plus the 2 closure conditions.
        n_unknowns: ``2N`` (instrument and polygon errors).
    """

    n_faces: int
    n_settings: int
    n_measurements: int
    n_equations: int
    n_unknowns: int


def closure_counts(n_faces: int, n_settings: int) -> ClosureCounts:
    """Measurements, equations and unknowns of a test with ``n_settings`` settings."""
    _check_counts(n_faces, n_settings)
    return ClosureCounts(
        n_faces=n_faces,
        n_settings=n_settings,
        n_measurements=n_settings * (n_faces + 1),
        n_equations=n_settings * n_faces + 2,
        n_unknowns=2 * n_faces,
    )


def _check_counts(n_faces: int, n_settings: int) -> None:
    if isinstance(n_faces, bool) or not isinstance(n_faces, int) or n_faces < 2:
        raise input_error("closure n_faces", f"got {n_faces!r}", "an integer >= 2")
    if isinstance(n_settings, bool) or not isinstance(n_settings, int) or n_settings < 1:
        raise input_error("closure n_settings", f"got {n_settings!r}", "an integer >= 1")


def _positions(n_faces: int, setting_positions: Sequence[int] | np.ndarray) -> np.ndarray:
    pos = np.asarray(setting_positions)
    if pos.ndim != 1 or pos.size < 1:
        raise input_error(
            "closure setting_positions", f"shape {pos.shape}", "a non-empty 1-D integer array"
        )
    if not np.issubdtype(pos.dtype, np.integer):
        if not np.all(np.isfinite(pos)) or np.any(pos != np.round(pos)):
            raise input_error("closure setting_positions", f"got {pos.tolist()}", "integers")
        pos = pos.astype(np.int64)
    return np.mod(pos.astype(np.int64), n_faces)


def closure_matrix(n_faces: int, setting_positions: Sequence[int] | np.ndarray) -> np.ndarray:
    """The seed's coefficient matrix, shape ``(S·N + 2, 2N)``.

    Columns: ``e_0 … e_{N−1}`` (instrument at positions 0 … N−1), then ``f_0 … f_{N−1}``
    (faces). Rows: for each setting ``s`` (in the given order) the ``N`` differences
    ``j → j+1`` of successive readings, then ``Σ e = 0`` and ``Σ f = 0``.
    """
    _check_counts(n_faces, 1)
    pos = _positions(n_faces, setting_positions)
    n = n_faces
    s_count = pos.size
    a = np.zeros((s_count * n + 2, 2 * n))
    j = np.arange(n)
    for s, p in enumerate(pos):
        rows = s * n + j
        q0 = (p + j) % n
        q1 = (p + j + 1) % n
        np.add.at(a, (rows, q1), 1.0)
        np.add.at(a, (rows, q0), -1.0)
        np.add.at(a, (rows, n + (j + 1) % n), 1.0)
        np.add.at(a, (rows, n + j), -1.0)
    a[-2, :n] = 1.0
    a[-1, n:] = 1.0
    return a


def undetermined_harmonics(
    n_faces: int, setting_positions: Sequence[int] | np.ndarray
) -> list[int]:
    """Harmonics ``k = 1 … ⌊N/2⌋`` that the settings cannot separate (see module doc).

    Harmonic k is undetermined when ``k (p_s − p_0) ≡ 0 (mod N)`` for every setting s.
    A single setting leaves every harmonic undetermined; a complete test none.
    """
    _check_counts(n_faces, 1)
    pos = _positions(n_faces, setting_positions)
    d = pos - pos[0]
    return [k for k in range(1, n_faces // 2 + 1) if np.all((k * d) % n_faces == 0)]


def _rank_deficit(n_faces: int, harmonics: Sequence[int]) -> int:
    return sum(1 if 2 * k == n_faces else 2 for k in harmonics)


def harmonic_amplitudes(values: np.ndarray) -> np.ndarray:
    """Amplitudes of harmonics ``0 … ⌊N/2⌋`` of a function sampled at N equally spaced
    positions (same units as ``values``): ``|c_0|`` and ``2|c_k|`` (``|c_{N/2}|``)."""
    v = np.asarray(values, dtype=float)
    n = v.shape[-1]
    spec = np.abs(np.fft.rfft(v, axis=-1)) / n
    spec[..., 1:] *= 2
    if n % 2 == 0:
        spec[..., -1] /= 2
    return spec


def _harmonic_basis(n: int) -> tuple[list[tuple[int, str]], np.ndarray]:
    """Rows that map N samples to the cos/sin amplitudes of harmonics 1 … N/2."""
    x = 2 * np.pi * np.arange(n) / n
    labels, rows = [], []
    for k in range(1, n // 2 + 1):
        w = 1.0 if 2 * k == n else 2.0
        labels.append((k, "cos"))
        rows.append(w * np.cos(k * x) / n)
        if 2 * k != n:
            labels.append((k, "sin"))
            rows.append(w * np.sin(k * x) / n)
    return labels, np.asarray(rows)


@dataclasses.dataclass(frozen=True)
class ClosureResult:
    """Result of :func:`solve_closure` (angles in rad).

    Attributes:
        status: ``"ok"`` or ``"rank_deficient"`` (then ``undetermined_harmonics`` is
            non-empty and the errors are the minimum-norm solution).
        counts: :class:`ClosureCounts`.
        setting_positions: face-0 position of each setting, ``(S,)``.
        rank: rank of the system (``2N`` when every harmonic is determined).
        dof: residual degrees of freedom ``S·N − rank + 2``.
        instrument_error_rad, instrument_se_rad: ``e_q`` at positions ``q = 0 … N−1``
            (``Σ e = 0``) and their standard errors, ``(N,)``.
        face_error_rad, face_se_rad: ``f_j`` of faces ``0 … N−1`` and standard errors.
        covariance_rad2: covariance of ``(e, f)``, ``(2N, 2N)``, rad².
        sigma_reading_rad: reading-noise standard deviation used for the errors: the
            residual estimate ``σ̂`` or the given ``sigma_reading_rad``.
        sigma_residual_rad: the residual estimate ``σ̂`` (0 when ``dof = 0``).
        chi2: whitened residual sum of squares over ``sigma_reading_rad²`` (``≈ dof``
            when the model and the noise level hold); only meaningful with a given σ.
        residual_rad: raw residual of each difference equation ``(S, N)``.
        closure_mismatch_rad: ``m_{s,N} − m_{s,0}`` per setting (drift during a setting).
        undetermined_harmonics: harmonics the settings cannot separate.
        harmonic_se_rad: standard error of the cos and sin amplitude of each instrument
            harmonic ``k = 1 … N/2``, dict ``k -> (se_cos, se_sin)``.
        weighting: ``"gls"`` (whitened differences) or ``"ols"`` (raw differences).
    """

    status: str
    counts: ClosureCounts
    setting_positions: np.ndarray
    rank: int
    dof: int
    instrument_error_rad: np.ndarray
    instrument_se_rad: np.ndarray
    face_error_rad: np.ndarray
    face_se_rad: np.ndarray
    covariance_rad2: np.ndarray
    sigma_reading_rad: float
    sigma_residual_rad: float
    chi2: float
    residual_rad: np.ndarray
    closure_mismatch_rad: np.ndarray
    undetermined_harmonics: list[int]
    harmonic_se_rad: dict[int, tuple[float, float]]
    weighting: str

    @property
    def n_faces(self) -> int:
        """Polygon faces N."""
        return self.counts.n_faces

    @property
    def positions_rad(self) -> np.ndarray:
        """Nominal instrument angles ``2πq/N`` of the positions, rad."""
        return 2 * np.pi * np.arange(self.n_faces) / self.n_faces

    def instrument_chi2(self, truth_rad: np.ndarray) -> tuple[float, int]:
        """``δᵀ C⁺ δ`` of an instrument-error truth (mean removed) against the estimate
        and its covariance, with its degrees of freedom (``N − 1`` when complete)."""
        n = self.n_faces
        t = np.asarray(truth_rad, dtype=float)
        d = self.instrument_error_rad - (t - t.mean())
        c = self.covariance_rad2[:n, :n]
        return float(d @ np.linalg.pinv(c, rcond=1e-10, hermitian=True) @ d), int(
            np.linalg.matrix_rank(c, tol=1e-10 * np.max(np.abs(c)), hermitian=True)
        )

    def face_chi2(self, truth_rad: np.ndarray) -> tuple[float, int]:
        """As :meth:`instrument_chi2` for the face errors."""
        n = self.n_faces
        t = np.asarray(truth_rad, dtype=float)
        d = self.face_error_rad - (t - t.mean())
        c = self.covariance_rad2[n:, n:]
        return float(d @ np.linalg.pinv(c, rcond=1e-10, hermitian=True) @ d), int(
            np.linalg.matrix_rank(c, tol=1e-10 * np.max(np.abs(c)), hermitian=True)
        )


def _difference_cholesky(n: int) -> np.ndarray:
    t = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    return np.linalg.cholesky(t)


def _lstsq(a: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """scipy's least squares (gelsd: it always returns the singular values; only gelsy gives
    None)."""
    return cast(
        "tuple[np.ndarray, np.ndarray, int, np.ndarray]",
        scipy.linalg.lstsq(a, y, cond=1e-10, check_finite=False),
    )


def solve_closure(
    readings_rad: np.ndarray,
    setting_positions: Sequence[int] | np.ndarray,
    *,
    sigma_reading_rad: float | None = None,
    weighting: str = "gls",
    throw: bool = True,
) -> ClosureResult:
    """Solve a dual-closure test by least squares.

    Args:
        readings_rad: instrument readings, rad, shape ``(S, N + 1)``: row s holds the
            readings at faces ``0, 1, …, N−1, 0`` of setting s (face 0 set down near
            position ``setting_positions[s]``). Readings may be wrapped to any interval;
            only their differences are used, unwrapped against the nominal step ``2π/N``.
        setting_positions: instrument position index (``0 … N−1``, steps of ``2π/N``) of
            face 0 in each setting, ``(S,)``. Repeated positions are allowed (repeats).
        sigma_reading_rad: known reading-noise standard deviation, rad. Default: the
            residual estimate (needs ``dof > 0``).
        weighting: ``"gls"`` (default; whitened differences, standard errors exact for
            white reading noise) or ``"ols"`` (raw differences, as the seed writes the
            system; standard errors from the sandwich ``A⁺ (σ² T) A⁺ᵀ``).
        throw: raise on a rank-deficient system (default). With ``False`` the result is
            returned with ``status = "rank_deficient"``.

    Returns:
        :class:`ClosureResult`.

    Raises:
        EncdesignInputError: bad shapes or values, or a rank-deficient system with
            ``throw=True`` (the message lists the undetermined harmonics).
    """
    r = np.asarray(readings_rad, dtype=float)
    if r.ndim != 2 or r.shape[1] < 3:
        raise input_error("closure readings_rad", f"shape {r.shape}", "(S, N + 1) with N >= 2")
    n = r.shape[1] - 1
    s_count = r.shape[0]
    pos = _positions(n, setting_positions)
    if pos.size != s_count:
        raise input_error(
            "closure setting_positions", f"{pos.size} positions", f"one per setting ({s_count})"
        )
    if not np.all(np.isfinite(r)):
        s, j = np.argwhere(~np.isfinite(r))[0]
        raise input_error(f"closure readings_rad[{s}, {j}]", f"got {r[s, j]!r}", "finite readings")
    if weighting not in ("gls", "ols"):
        raise input_error("closure weighting", f"got {weighting!r}", "'gls' or 'ols'")
    if sigma_reading_rad is not None and not (
        math.isfinite(sigma_reading_rad) and sigma_reading_rad > 0
    ):
        raise input_error(
            "closure sigma_reading_rad", f"got {sigma_reading_rad!r}", "a positive number"
        )
    counts = closure_counts(n, s_count)
    step = 2 * np.pi / n
    raw = np.diff(r, axis=1)  # (S, N)
    # unwrap each difference to the nominal step; the last one returns to face 0
    d = raw - step
    d = d - 2 * np.pi * np.round(d / (2 * np.pi))
    if np.any(np.abs(d) > step / 4):
        s, j = np.argwhere(np.abs(d) > step / 4)[0]
        raise input_error(
            f"closure readings_rad[{s}, {j + 1}]",
            f"step from face {j} to face {(j + 1) % n} is {math.degrees(raw[s, j]) % 360:.6g} deg",
            f"about {math.degrees(step):.6g} deg (faces in the order of increasing reading)",
        )
    mismatch = d.sum(axis=1)
    a = closure_matrix(n, pos)
    und = undetermined_harmonics(n, pos)
    if und and throw:
        raise EncdesignInputError(
            f"closure: rank-deficient system ({s_count} settings at positions "
            f"{sorted(set(pos.tolist()))} of {n}): harmonics {und} of the instrument and the "
            "polygon cannot be separated (add settings whose position differences k·Δp "
            "are not multiples of N)"
        )
    a_diff = a[:-2]
    gauge = a[-2:]
    if weighting == "gls":
        ell = _difference_cholesky(n)
        aw = scipy.linalg.solve_triangular(
            ell, a_diff.reshape(s_count, n, 2 * n), lower=True, check_finite=False
        )
        aw = aw.reshape(s_count * n, 2 * n)
        yw = scipy.linalg.solve_triangular(ell, d.T, lower=True, check_finite=False).T.reshape(-1)
    else:
        aw, yw = a_diff, d.reshape(-1)
    a_full = np.vstack([aw, gauge])
    y_full = np.concatenate([yw, np.zeros(2)])
    x, _, rank, sv = _lstsq(a_full, y_full)
    rank = int(rank)
    expected_rank = 2 * n - _rank_deficit(n, und)
    if rank != expected_rank:  # numerical trouble: never hide it
        raise EncdesignInputError(
            f"closure: numerical rank {rank} differs from the structural rank "
            f"{expected_rank} (singular values {sv.min():.3g} … {sv.max():.3g})"
        )
    raw_resid = (d.reshape(-1) - a_diff @ x).reshape(s_count, n)
    # the whitened residual: white with variance σ² under the model, for either weighting
    ell = _difference_cholesky(n)
    white = scipy.linalg.solve_triangular(ell, raw_resid.T, lower=True, check_finite=False).T
    rss = float(np.sum(white**2))
    dof = s_count * n - rank + 2
    sigma_hat = math.sqrt(rss / dof) if dof > 0 else 0.0
    if sigma_reading_rad is None:
        if dof <= 0:
            raise input_error(
                "closure",
                f"no residual degrees of freedom ({s_count} settings of {n} faces)",
                "more settings, or a known sigma_reading_rad",
            )
        sigma = sigma_hat
    else:
        sigma = float(sigma_reading_rad)
    pinv = np.linalg.pinv(a_full, rcond=1e-10)[:, : s_count * n]
    if weighting == "gls":
        cov = sigma**2 * pinv @ pinv.T
    else:  # sandwich: A⁺ (σ² T) A⁺ᵀ, T block-diagonal over settings
        t = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
        p3 = pinv.reshape(2 * n, s_count, n)
        cov = sigma**2 * np.einsum("asi,ij,bsj->ab", p3, t, p3)
    chi2 = rss / sigma**2 if sigma > 0 else 0.0
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    labels, basis = _harmonic_basis(n)
    hcov = basis @ cov[:n, :n] @ basis.T
    hse: dict[int, list[float]] = {}
    for (k, kind), v in zip(labels, np.sqrt(np.clip(np.diag(hcov), 0.0, None))):
        hse.setdefault(k, [0.0, 0.0])[0 if kind == "cos" else 1] = float(v)
    return ClosureResult(
        status="rank_deficient" if und else "ok",
        counts=counts,
        setting_positions=pos,
        rank=rank,
        dof=int(dof),
        instrument_error_rad=x[:n],
        instrument_se_rad=se[:n],
        face_error_rad=x[n:],
        face_se_rad=se[n:],
        covariance_rad2=cov,
        sigma_reading_rad=float(sigma),
        sigma_residual_rad=float(sigma_hat),
        chi2=float(chi2),
        residual_rad=raw_resid,
        closure_mismatch_rad=mismatch,
        undetermined_harmonics=und,
        harmonic_se_rad={k: (v[0], v[1]) for k, v in hse.items()},
        weighting=weighting,
    )


def closure_from_recording(
    rec,
    *,
    sigma_reading_rad: float | None = None,
    weighting: str = "gls",
    throw: bool = True,
) -> ClosureResult:
    """:func:`solve_closure` on a ``closure`` recording (``docs/recording-format.md``);
    the face-0 position of each setting is taken from its first reading."""
    from ..io._closure_recording import closure_arrays

    readings, positions, _ = closure_arrays(rec)
    try:
        return solve_closure(
            readings,
            positions,
            sigma_reading_rad=sigma_reading_rad,
            weighting=weighting,
            throw=throw,
        )
    except EncdesignInputError as exc:
        where = str(rec.path) if rec.path is not None else "closure recording"
        raise EncdesignInputError(f"{where}: {exc}") from None


def closure_null_angles(
    n_faces: int,
    setting_positions: Sequence[int] | np.ndarray,
    face_error_rad: np.ndarray,
    setting_offset_rad: np.ndarray,
) -> np.ndarray:
    """True platform angle at each null of a dual-closure test, ``(S, N + 1)``, rad:
    ``2π (p_s + j)/N + offset_s + f_{j mod N}`` (faces ``0 … N−1``, then face 0)."""
    pos = _positions(n_faces, setting_positions)
    f = np.asarray(face_error_rad, dtype=float).reshape(-1)
    off = np.asarray(setting_offset_rad, dtype=float).reshape(-1)
    if f.size != n_faces or off.size != pos.size:
        raise input_error(
            "closure_null_angles",
            f"{f.size} face errors, {off.size} offsets",
            f"{n_faces} and {pos.size}",
        )
    j = np.arange(n_faces + 1)
    return 2 * np.pi * (pos[:, None] + j) / n_faces + off[:, None] + f[j % n_faces][None, :]
