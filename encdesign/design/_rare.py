"""Rare-event yield: FORM design points and defensive-mixture importance sampling.

A build fails when its metric exceeds the spec, ``m(z) > spec``, where ``z`` is the build's
standard-normal vector (:func:`encdesign.design.build_normals`; the deviations are
``sigma_i z_i``). For yields of 99.9 %–99.9999 % crude Monte Carlo needs ``~100 / P_f``
builds for a 10 % error. Here instead:

1. **FORM design points.** The most probable failure point is the point of the limit-state
   surface ``m(z) = spec`` nearest the origin, ``z* = argmin |z|`` s.t. ``m(z) >= spec``.
   It is found by gradient: from the leading eigenvectors of the Hessian of ``m(z)^2`` at the
   nominal build (an RMS metric squared is nearly a quadratic form) and from ``n_starts``
   random directions, a bisection along the ray to the surface, then the
   Hasofer–Lind–Rackwitz–Fiessler iteration
   ``z <- ((grad G . z - G) / |grad G|^2) grad G`` on ``G = (spec - m) / spec`` (``jax.grad``
   of the metric), each start also run from the mirror image ``-z*``. Distinct converged
   points within ``beta_window`` of the smallest ``beta = |z*|`` are kept (an RMS residual is
   often nearly even in ``z``, and rotationally symmetric effects such as eccentricity give
   several equally probable failure points). ``Phi(-beta)`` is the FORM approximation.
2. **Defensive mixture importance sampling.** Samples come from
   ``q(z) = alpha phi(z) + (1 - alpha) sum_k pi_k phi(z - z*_k)``, ``pi_k ~ Phi(-beta_k)``;
   the nominal component (weight ``alpha``) bounds every weight ``phi/q <= 1/alpha``, so the
   estimate stays unbiased and its variance finite even where the design points miss part
   of the failure region. ``P_f = mean(w 1_F)``, standard error ``std(w 1_F)/sqrt(n)``.
3. **Likelihood-ratio gradient.** Write a build in physical deviations ``x = sigma_g z`` for
   the components ``z`` of tolerance group ``g``. The density of ``x`` depends on ``sigma_g``
   with score ``d ln p / d sigma_g = sum_{c in g} (z_c^2 - 1) / sigma_g``, so
   ``dP_f/dsigma_g = E_q[w 1_F sum_{c in g} (z_c^2 - 1)] / sigma_g`` (same samples, with a
   standard error). It needs no derivative of the indicator. Tolerances that are not
   sampled (e.g. read noise entering through its expected mean square) have none.

Every metric evaluation is a build and is counted (``n_builds_total``), FORM included.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from scipy.special import ndtr

from .._errors import EncdesignInputError
from ._sampling import VECTOR_BUILDS, values_of_normals
from ._status import NONFINITE, SUCCESS, DriverStatus

VECTOR = VECTOR_BUILDS

__all__ = ["RareEventResult", "form_design_points", "importance_yield"]

NO_FAILURE = DriverStatus.NO_FAILURE_FOUND


@functools.lru_cache(maxsize=32)
def _compiled(metric_z: Callable[..., jax.Array], vector: int) -> dict[str, Any]:
    """Jitted pieces for ``metric_z`` (cached: repeated calls with the same function, e.g. an
    allocation's bisection passing new tolerances as ``args``, compile once)."""

    def m(z, a):
        return metric_z(z) if a is None else metric_z(z, a)

    return {
        "vg": jax.jit(jax.value_and_grad(lambda z, a, spec: (spec - m(z, a)) / spec)),
        "ray": jax.jit(jax.vmap(lambda r, d, a: m(r * d, a), in_axes=(0, None, None))),
        "point": jax.jit(m),
        "hess": jax.jit(jax.hessian(lambda z, a: m(z, a) ** 2)),
        "batch": jax.jit(lambda zc, a: values_of_normals(lambda zi: m(zi, a), zc, vector)),
    }


@dataclasses.dataclass(frozen=True)
class RareEventResult:
    """Result of :func:`importance_yield`.

    Attributes:
        failure_prob: estimated ``P(m > spec)``.
        failure_stderr: its standard error.
        n_builds: importance samples (metric evaluations of the estimate).
        n_form_builds: metric (and gradient) evaluations spent finding design points.
        design_points: ``(K, dim)`` FORM design points used in the mixture.
        betas: ``(K,)`` their reliability indices ``|z*|``.
        form_failure_prob: ``Phi(-beta_min)`` (FORM's own estimate, no error bar).
        lr_gradient: ``dP_f/dsigma_g`` per tolerance group (1 / SI unit of the tolerance),
            ``None`` without groups.
        lr_gradient_stderr: standard errors of ``lr_gradient``.
        names: group names (``None`` without groups).
        n_failures: importance samples in the failure region.
        defensive: the nominal component's weight ``alpha``.
        wall_s: wall time, s.
        status: ``"success"``, or ``"no_failure_found"`` (no start reached the spec within
            ``r_max`` standard deviations: ``P_f < Phi(-r_max)``, not estimated).
        message: account of the status.
    """

    failure_prob: float
    failure_stderr: float
    n_builds: int
    n_form_builds: int
    design_points: np.ndarray
    betas: np.ndarray
    form_failure_prob: float
    lr_gradient: np.ndarray | None
    lr_gradient_stderr: np.ndarray | None
    names: tuple[str, ...] | None
    n_failures: int
    defensive: float
    wall_s: float
    status: DriverStatus
    message: str = ""

    @property
    def ok(self) -> bool:
        """True when the status is an answer (:attr:`DriverStatus.ok`: ``success``)."""
        return self.status.ok

    def _repr_html_(self) -> str:
        """Jupyter's rich display: the status and the key numbers."""
        from ._display import rare_event_html

        return rare_event_html(self)

    @property
    def yield_fraction(self) -> float:
        """``1 - failure_prob``."""
        return 1.0 - self.failure_prob

    @property
    def n_builds_total(self) -> int:
        """All metric evaluations: importance samples plus FORM."""
        return self.n_builds + self.n_form_builds

    def as_dict(self) -> dict[str, Any]:
        """JSON-able summary."""
        out = {
            "yield": self.yield_fraction,
            "yield_stderr": self.failure_stderr,
            "failure_prob": self.failure_prob,
            "failure_stderr": self.failure_stderr,
            "form_failure_prob": self.form_failure_prob,
            "betas": [float(b) for b in self.betas],
            "n_builds": self.n_builds,
            "n_form_builds": self.n_form_builds,
            "n_builds_total": self.n_builds_total,
            "n_failures": self.n_failures,
            "defensive": self.defensive,
            "wall_s": self.wall_s,
            "status": self.status,
            "message": self.message,
        }
        grad, grad_se, names = self.lr_gradient, self.lr_gradient_stderr, self.names
        if grad is not None and grad_se is not None and names is not None:
            out["lr_gradient"] = dict(zip(names, map(float, grad)))
            out["lr_gradient_stderr"] = dict(zip(names, map(float, grad_se)))
        return out


def form_design_points(
    metric_z: Callable[[jax.Array], jax.Array],
    dim: int,
    spec: float,
    *,
    key: jax.Array,
    n_starts: int = 4,
    n_hessian: int = 8,
    max_steps: int = 40,
    r_max: float = 12.0,
    beta_window: float = 1.0,
    n_deflations: int = 2,
    tol: float = 1e-5,
    args: Any = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """FORM design points of ``metric_z(z) > spec`` (module docstring).

    Args:
        metric_z: per-build metric of a standard-normal vector ``z [dim]`` (JAX,
            differentiable).
        dim: length of ``z``.
        spec: failure threshold (units of the metric).
        key: PRNG key of the start directions.
        n_starts: random start directions.
        n_hessian: start directions from the leading eigenvectors of the Hessian of
            ``metric_z**2`` at ``z = 0`` (each also mirrored).
        max_steps: HL-RF iterations per start.
        r_max: rays that stay within spec up to ``|z| = r_max`` are dropped.
        beta_window: keep design points with ``beta <= beta_min + beta_window``.
        n_deflations: after the random starts, further searches restricted to the
            orthogonal complement of the points found so far (secondary design points of a
            failure region that wraps round the origin, such as the outside of the ellipsoid
            of an RMS metric); each is also mirrored.
        tol: convergence of a point (step length, in standard deviations) and of the limit
            state ``|G| = |spec - m| / spec``.
        args: when given, the metric is ``metric_z(z, args)`` (e.g. the tolerances), so the
            same function compiles once for many ``args``.

    Returns:
        ``(points [K, dim], betas [K], n_evaluations)``; ``K = 0`` when no start reached the
        failure region.
    """
    spec = float(spec)
    fns = _compiled(metric_z, VECTOR)
    spec_j = jnp.asarray(spec)

    def g_vg(z):
        return fns["vg"](z, args, spec_j)

    def ray(r, d):
        return fns["ray"](r, d, args)

    n_eval = 0
    dirs = np.array(jax.random.normal(key, (n_starts, dim)))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)

    def hlrf(z: np.ndarray, basis: np.ndarray | None = None) -> tuple[np.ndarray | None, int]:
        used = 0
        for _ in range(max_steps):
            g, dg = g_vg(jnp.asarray(z))
            g, dg = float(g), np.asarray(dg)
            if basis is not None:  # search within the orthogonal complement of ``basis``
                dg = dg - basis.T @ (basis @ dg)
            used += 1
            nrm2 = float(dg @ dg)
            if not (math.isfinite(g) and math.isfinite(nrm2)) or nrm2 == 0.0:
                return None, used
            z_new = ((dg @ z - g) / nrm2) * dg
            step = float(np.linalg.norm(z_new - z))
            if step > 2.0:  # damped: keep each step within two standard deviations
                z_new = z + (z_new - z) * (2.0 / step)
            z = z_new
            if step < tol and abs(g) < tol:
                return z, used
        g, _ = g_vg(jnp.asarray(z))
        used += 1
        return (z if abs(float(g)) < 1e3 * tol else None), used

    found: list[np.ndarray] = []
    radii = np.linspace(0.25, r_max, 48)

    def search(d: np.ndarray, basis: np.ndarray | None) -> int:
        """Ray bisection along ``d`` to the surface, HL-RF, then its mirror image; appends
        to ``found`` and returns the evaluations used."""
        used = radii.size
        vals = np.asarray(ray(jnp.asarray(radii), jnp.asarray(d)))
        over = np.flatnonzero(vals > spec)
        if over.size == 0:
            return used
        i = over[0]
        lo, hi = (radii[i - 1] if i > 0 else 0.0), radii[i]
        for _ in range(20):  # bisection along the ray to the limit-state surface
            mid = 0.5 * (lo + hi)
            used += 1
            if float(fns["point"](jnp.asarray(mid * d), args)) > spec:
                hi = mid
            else:
                lo = mid
        z, k = hlrf(hi * d, basis)
        used += k
        if z is None:
            return used
        found.append(z)
        zm, k = hlrf(-z, basis)  # the mirror image: nearly even metrics fail on both sides
        used += k
        if zm is not None:
            found.append(zm)
        return used

    if n_hessian > 0:
        # curvature of m^2 at the nominal build: for an RMS metric m^2 is nearly a quadratic
        # form z' Q z whose leading eigenvectors point at the nearest failures (random
        # directions in many dimensions mostly miss them)
        hess = np.asarray(fns["hess"](jnp.zeros(dim), args))
        n_eval += dim
        evals, evecs = np.linalg.eigh(0.5 * (hess + hess.T))
        for k in np.argsort(-evals)[: min(n_hessian, dim)]:
            if evals[k] > 0:
                n_eval += search(evecs[:, k], None)
    for d in dirs:
        n_eval += search(d, None)
    kd = jax.random.fold_in(key, 1)
    for r in range(n_deflations if found else 0):
        q, _ = np.linalg.qr(np.stack(found, axis=1))
        basis = q.T  # orthonormal rows spanning the points found so far
        d = np.asarray(jax.random.normal(jax.random.fold_in(kd, r), (dim,)))
        d = d - basis.T @ (basis @ d)
        if np.linalg.norm(d) < 1e-9:
            break
        n_eval += search(d / np.linalg.norm(d), basis)
    if not found:
        return np.zeros((0, dim)), np.zeros(0), n_eval
    pts = sorted(found, key=lambda z: float(np.linalg.norm(z)))
    keep: list[np.ndarray] = []
    for z in pts:
        nz = np.linalg.norm(z)
        if all(np.linalg.norm(z - k) > 0.05 * max(nz, 1.0) for k in keep):
            keep.append(z)
    betas = np.array([np.linalg.norm(z) for z in keep])
    sel = betas <= betas[0] + beta_window
    return np.stack(keep)[sel], betas[sel], n_eval


def importance_yield(
    metric_z: Callable[..., jax.Array],
    dim: int,
    spec: float,
    *,
    key: jax.Array,
    n: int = 4096,
    defensive: float = 0.1,
    n_starts: int = 8,
    groups: Sequence[int] | None = None,
    sigmas: Sequence[float] | None = None,
    names: Sequence[str] | None = None,
    chunk_size: int = 512,
    r_max: float = 12.0,
    n_deflations: int = 2,
    beta_window: float = 1.0,
    n_hessian: int = 8,
    args: Any = None,
) -> RareEventResult:
    """Failure probability ``P(metric_z(z) > spec)``, ``z ~ N(0, I_dim)``, by
    defensive-mixture importance sampling around FORM design points (module docstring).

    Args:
        metric_z: per-build metric of ``z [dim]`` (JAX, differentiable for FORM).
        dim: length of ``z``.
        spec: failure threshold (metric units).
        key: PRNG key (FORM starts, mixture components, samples).
        n: importance samples.
        defensive: weight ``alpha`` of the nominal component (0 < alpha < 1).
        n_starts: FORM start directions.
        groups: tolerance group of each component of ``z`` (``-1``: none), for the
            likelihood-ratio gradient.
        sigmas: the groups' standard deviations (SI), indexed by group.
        names: the groups' names.
        chunk_size: builds evaluated per jitted call (memory bound; builds are vectorised
            :data:`~encdesign.design._drivers.VECTOR_BUILDS` at a time within a call).
        r_max, n_deflations, beta_window, n_hessian, args: see
            :func:`form_design_points`.

    Returns:
        :class:`RareEventResult`.
    """
    if not 0.0 < defensive < 1.0:
        raise EncdesignInputError(f"defensive: {defensive!r}, expected 0 < alpha < 1")
    t0 = time.perf_counter()
    k_form, k_comp, k_z = jax.random.split(key, 3)
    nominal_fails = float(_compiled(metric_z, VECTOR)["point"](jnp.zeros(dim), args)) > spec
    if nominal_fails:  # not a rare event: the nominal build fails; plain sampling
        pts, betas, n_form = np.zeros((0, dim)), np.zeros(0), 1
    else:
        pts, betas, n_form = form_design_points(
            metric_z, dim, spec, key=k_form, n_starts=n_starts, r_max=r_max,
            n_deflations=n_deflations, beta_window=beta_window, n_hessian=n_hessian,
            args=args,
        )  # fmt: skip
    if pts.shape[0] == 0 and not nominal_fails:
        return RareEventResult(
            0.0, 0.0, 0, n_form, pts, betas, float(ndtr(-r_max)), None, None, None, 0,
            defensive, time.perf_counter() - t0, NO_FAILURE,
            f"no start direction reached the spec within {r_max} standard deviations "
            f"(P_f < {float(ndtr(-r_max)):.3g})",
        )  # fmt: skip
    zn = np.asarray(jax.random.normal(k_z, (n, dim)))
    if nominal_fails:
        z, w = zn, np.ones(n)
    else:
        logpi = np.log(np.maximum(ndtr(-betas), 1e-300))
        pi = np.exp(logpi - logpi.max())
        pi /= pi.sum()
        n_nom = int(np.sum(np.asarray(jax.random.uniform(k_comp, (n,))) < defensive))
        comp = np.asarray(
            jax.random.choice(jax.random.fold_in(k_comp, 1), pts.shape[0], (n - n_nom,), p=pi)
        )
        shift = np.zeros((n, dim))
        shift[n_nom:] = pts[comp]
        z = zn + shift
        # w = phi(z) / q(z) = 1 / (alpha + (1 - alpha) sum_k pi_k exp(z.z_k - |z_k|^2 / 2))
        expo = z @ pts.T - 0.5 * np.sum(pts * pts, axis=1)[None, :] + np.log(pi)[None, :]
        m = np.max(expo, axis=1, keepdims=True)
        lse = (m[:, 0] + np.log(np.sum(np.exp(expo - m), axis=1))) + math.log(1.0 - defensive)
        w = np.exp(-np.logaddexp(math.log(defensive), lse))
    size = -(-chunk_size // VECTOR) * VECTOR
    batch = _compiled(metric_z, VECTOR)["batch"]

    def f(zc):
        return batch(zc, args)

    vals = np.empty(n)
    for s in range(0, n, size):
        zc = z[s : s + size]
        pad = size - zc.shape[0]
        zc = np.concatenate([zc, np.zeros((pad, dim))]) if pad else zc
        vals[s : s + size] = np.asarray(f(jnp.asarray(zc)))[: size - pad]
    if not np.all(np.isfinite(vals)):
        bad = int(np.sum(~np.isfinite(vals)))
        return RareEventResult(
            math.nan, math.nan, n, n_form, pts, betas,
            (float(ndtr(-betas[0])) if betas.size else math.nan), None, None, None, 0,
            defensive, time.perf_counter() - t0, NONFINITE,
            f"{bad} of {n} importance samples gave a non-finite metric",
        )  # fmt: skip
    fail = vals > spec
    contrib = w * fail
    pf = float(np.mean(contrib))
    se = float(np.std(contrib, ddof=1) / math.sqrt(n))
    grad = grad_se = None
    gnames = None
    if groups is not None:
        gidx = np.asarray(groups, dtype=int)
        if gidx.shape != (dim,):
            raise EncdesignInputError(f"groups: shape {gidx.shape}, expected ({dim},)")
        sig = np.asarray(sigmas, dtype=np.float64)
        n_groups = sig.size
        gnames = tuple(names) if names is not None else tuple(str(i) for i in range(n_groups))
        score = np.zeros((n, n_groups))
        for gi in range(n_groups):
            cols = gidx == gi
            if cols.any() and sig[gi] > 0:
                score[:, gi] = np.sum(z[:, cols] ** 2 - 1.0, axis=1) / sig[gi]
        terms = contrib[:, None] * score
        grad = np.mean(terms, axis=0)
        grad_se = np.std(terms, axis=0, ddof=1) / math.sqrt(n)
        unsampled = np.array([not np.any(gidx == gi) or sig[gi] <= 0 for gi in range(n_groups)])
        grad = np.where(unsampled, np.nan, grad)
        grad_se = np.where(unsampled, np.nan, grad_se)
    return RareEventResult(
        pf,
        se,
        n,
        n_form,
        pts,
        betas,
        (float(ndtr(-betas[0])) if betas.size else math.nan),
        grad,
        grad_se,
        gnames,
        int(np.sum(fail)),
        defensive,
        time.perf_counter() - t0,
        SUCCESS,
        (
            f"{pts.shape[0]} design point(s), beta_min = {betas[0]:.3f}"
            if betas.size
            else "the nominal build fails: plain Monte Carlo (not a rare event)"
        ),
    )
