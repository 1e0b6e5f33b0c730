"""A term's nonlinear parameters as linear tangents (``engine/_tangent.py``, issue 44 C): the
tangent of the multihead base in its run angle zeros and head placements, by its hand-written
Jacobian and by ``jax.jvp`` of its function, against a finite difference of the base."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from encdesign.diagnose.engine._tangent import PREFIX, _tangent
from encdesign.diagnose.kinds.multihead._multihead import _base_candidate


def test_the_base_tangent_is_its_first_order_move():
    C, R, M, n = 3, 2, 5, 200
    rng = np.random.default_rng(0)
    base = _base_candidate(C, R, M)
    names = ("placement_rad", "run_angle_offset_rad")
    tan = _tangent(base, names)
    run = (np.arange(n) >= n // 2).astype(int)
    x = {
        "theta_raw": jnp.asarray(np.linspace(0.0, 4.0, n)),
        "run_onehot": jnp.asarray(np.eye(R)[run]),
        "alpha": jnp.asarray([0.0, 2.0, 4.1]),
    }
    p = {
        "offset_rad": jnp.asarray(rng.normal(size=(R, C))),
        "fourier_cos_rad": jnp.asarray(rng.normal(size=M) * 1e-5),
        "fourier_sin_rad": jnp.asarray(rng.normal(size=M) * 1e-5),
        "placement_rad": jnp.asarray(rng.normal(size=C - 1) * 1e-3),
        "run_angle_offset_rad": jnp.asarray(rng.normal(size=R - 1) * 1e-2),
    }
    d = {n_: jnp.asarray(rng.normal(size=np.shape(p[n_]))) for n_ in names}
    h = 1e-6
    moved = {**p, **{n_: p[n_] + h * d[n_] for n_ in names}}
    fd = (np.asarray(base.fn(moved, x)) - np.asarray(base.fn(p, x))) / h
    pt = {**p, **{PREFIX + n_: d[n_] for n_ in names}}
    by_jvp = np.asarray(tan.fn(pt, x))
    assert tan.valjac is not None
    by_hand, J = tan.valjac(pt, x)
    scale = np.max(np.abs(fd))
    assert scale > 0
    assert np.allclose(by_jvp, fd, atol=1e-4 * scale)
    assert np.allclose(np.asarray(by_hand), by_jvp, atol=1e-10 * scale)
    assert set(J) == {PREFIX + n_ for n_ in names}
    zero = {**p, **{PREFIX + n_: jnp.zeros_like(d[n_]) for n_ in names}}
    assert np.all(np.asarray(tan.fn(zero, x)) == 0.0)  # adds columns, not a prediction
