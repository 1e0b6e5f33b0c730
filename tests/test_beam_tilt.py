"""The multihead ``beam_tilt_axial`` term's hand-written Jacobians (issue 43,
``kinds/multihead/_beam_tilt.py``): its factored Jacobian ``J = X W`` (what the fitter uses,
never compiled) and its JAX ``valjac`` against ``jax.jacfwd`` of the candidate's ``fn`` and
against finite differences, its real projector against the complex basis, and the one
compiled program a hand-written ``valjac`` shares between the fitter's full and linear
Jacobians."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import encdesign  # noqa: F401  (float64)
from encdesign.diagnose.engine._normal import factors_of
from encdesign.diagnose.kinds.multihead._beam_tilt import _bt_basis, bt_projectors
from encdesign.diagnose.kinds.multihead._multihead_probes import (
    BEAM_TILT_AXIAL,
    BEAM_TILT_AXIAL_NO_REF,
)
from encdesign.diagnose.kinds.multihead._runout import RUNOUT_ORDERS

CASES = [
    (False, (0.0, 1.6, 3.1, 4.7)),
    (True, (0.0, 1.6, 3.1, 4.7)),
    (True, (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi)),  # order 2 and 3: the common mode's span
    (False, (0.0, 2.1, 4.4)),
]


def _record(project: bool, alpha, seed: int, n: int = 240):
    cand = BEAM_TILT_AXIAL_NO_REF if project else BEAM_TILT_AXIAL
    rng = np.random.default_rng(seed)
    C = len(alpha)
    x = {"alpha": jnp.asarray(alpha), "theta": jnp.asarray(rng.uniform(0.0, 60.0, n))}
    p = {q.name: jnp.asarray(rng.normal(0, 1e-6, q.resolved_shape(C, 2))) for q in cand.params}
    p["orders_on"] = jnp.asarray([1.0, 0.0, 1.0])
    return cand, p, x


def _linear_names(cand) -> list[str]:
    return [q.name for q in cand.params if q.linear]


@pytest.mark.parametrize("project,alpha", CASES)
def test_projector_equals_the_complex_basis(project, alpha):
    a = np.asarray(alpha)
    Pr, Pi = bt_projectors(a, project)
    for j, m in enumerate(RUNOUT_ORDERS):
        Q = np.asarray(_bt_basis(jnp.asarray(a), m, project))
        P = np.eye(a.size) - Q.T @ np.conj(Q)
        np.testing.assert_allclose(Pr[j], P.real, rtol=0, atol=1e-15)
        np.testing.assert_allclose(Pi[j], P.imag, rtol=0, atol=1e-15)


@pytest.mark.parametrize("project,alpha", CASES)
def test_hand_jacobians_equal_jacfwd(project, alpha):
    """The factored Jacobian (linear columns, and with ``full`` every column and the value)
    and the JAX ``valjac`` against ``jax.jacfwd(fn)``, to rounding."""
    cand, p, x = _record(project, alpha, 7461)
    n, C = x["theta"].shape[0], len(alpha)
    f = np.asarray(jax.jit(cand.fn)(p, x))
    Jf = jax.jit(jax.jacfwd(cand.fn))(p, x)
    scale = float(np.max(np.abs(np.asarray(Jf["cos1_rad"]))))
    v, J = jax.jit(cand.valjac)(p, x)
    np.testing.assert_allclose(np.asarray(v), f, rtol=0, atol=1e-14 * np.max(np.abs(f)))
    assert set(J) == set(Jf)
    for k in Jf:
        assert J[k].shape == Jf[k].shape, k
        np.testing.assert_allclose(np.asarray(J[k]), np.asarray(Jf[k]), rtol=0, atol=1e-14 * scale)
    factors = factors_of(cand)
    assert factors is not None
    free = {q.name: np.ones(q.resolved_shape(C, 2), bool) for q in cand.params}
    free["orders_on"][:] = False
    free["sin2_rad"][1] = False  # a held scalar: its column left out
    names = _linear_names(cand)

    def wanted(keys):
        return np.concatenate(
            [np.asarray(Jf[k]).reshape(n, C, -1)[:, :, free[k].ravel()] for k in keys], 2
        )

    v0, X, W, E = factors(p, x, free, n)
    assert E is None and X.shape == (n, 2 * len(RUNOUT_ORDERS))
    np.testing.assert_array_equal(v0, np.zeros((n, C)))
    J1 = np.einsum("nf,fck->nck", X, W)
    np.testing.assert_allclose(J1, wanted(names), rtol=0, atol=1e-14 * scale)
    free["orders_on"][:] = True
    vf, X, W, E = factors(p, x, free, n, full=True)
    np.testing.assert_allclose(vf, f, rtol=0, atol=1e-14 * np.max(np.abs(f)))
    J2 = np.einsum("nf,fck->nck", X, W)
    np.testing.assert_allclose(J2, wanted([*names, "orders_on"]), rtol=0, atol=1e-14 * scale)


@pytest.mark.parametrize("project", [False, True])
def test_gradient_matches_finite_differences(project):
    """``fn`` stays differentiable: ``jax.grad`` of a squared residual, and the factored
    Jacobian's gradient, against central differences (the term is linear in these
    parameters, so the differences are exact to rounding)."""
    cand, p, x = _record(project, CASES[1][1], 7462)
    n, C = x["theta"].shape[0], 4
    y = jnp.asarray(np.random.default_rng(7463).normal(0, 1e-6, (n, C)))

    def loss(q):
        return jnp.sum((cand.fn(q, x) - y) ** 2)

    g = jax.grad(loss)(p)
    free = {q.name: np.ones(q.resolved_shape(C, 2), bool) for q in cand.params}
    free["orders_on"][:] = False
    _, X, W, _ = factors_of(cand)(p, x, free, n)
    r = np.asarray(cand.fn(p, x) - y)
    gf = 2.0 * np.einsum("nc,nf,fck->k", r, X, W)  # the chain rule through J = X W
    h = 1e-8
    at = 0
    for name in _linear_names(cand):
        for i in range(C):
            up = dict(p)
            dn = dict(p)
            up[name] = p[name].at[i].add(h)
            dn[name] = p[name].at[i].add(-h)
            fd = float(loss(up) - loss(dn)) / (2 * h)
            size = max(abs(fd), 1e-300)
            assert abs(float(g[name][i]) - fd) <= 1e-6 * size + 1e-20, (name, i)
            assert abs(gf[at] - fd) <= 1e-6 * size + 1e-20, (name, i)
            at += 1


def test_hand_valjac_compiles_once_for_the_full_and_the_linear_jacobian():
    """Issue 43: a hand-written ``valjac`` is one compiled program, whether the fitter asks
    for every column (``_fit.valjac_fn``) or the linear ones (``_normal.linear_valjac``);
    main compiled a second one keeping only the linear tangents."""
    from jax import monitoring

    from encdesign.diagnose.engine._fit import valjac_fn
    from encdesign.diagnose.engine._normal import linear_valjac
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    rng = np.random.default_rng(7464)
    n, C, R = 120, 3, 2
    oh = np.zeros((n, R))
    oh[np.arange(n), rng.integers(0, R, n)] = 1.0
    x = {
        "run_onehot": jnp.asarray(oh),
        "t": jnp.asarray(np.sort(rng.uniform(0, 20, n))),
        "reading": jnp.zeros((n, C)),
    }
    p = {q.name: jnp.asarray(rng.normal(0, 1e-6, q.resolved_shape(C, R))) for q in VIBRATION.params}
    p["frequency_hz"] = jnp.asarray(23.9)
    v, J = valjac_fn(VIBRATION)(p, x)
    compiles = []

    def listen(event: str, duration: float, **_) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(duration)

    monitoring.register_event_duration_secs_listener(listen)
    try:
        vl, Jl = linear_valjac(VIBRATION)(p, x)
    finally:
        monitoring.unregister_event_duration_listener(listen)
    assert compiles == []
    assert set(Jl) == {q.name for q in VIBRATION.params if q.linear}
    np.testing.assert_array_equal(np.asarray(vl), np.asarray(v))
    for k in Jl:
        np.testing.assert_array_equal(np.asarray(Jl[k]), np.asarray(J[k]))
