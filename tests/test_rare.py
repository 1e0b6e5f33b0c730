"""Rare-event yield: FORM design points, defensive-mixture importance sampling and the
likelihood-ratio gradient, against closed forms (issue 14). The comparison with crude Monte
Carlo of 10^6 encoder builds is ``benchmarks/optimize.py --rare``."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import ndtr

from encdesign.design import form_design_points, importance_yield

SIG = np.array([1.0, 1.0, 0.3])  # group standard deviations (the third is a bystander)


def _rayleigh(sig):
    """Metric of deviations sigma_g z_g: radius of the first two (a rotationally symmetric
    failure region, every point of a circle is a design point)."""
    return lambda z: jnp.sqrt((sig[0] * z[0]) ** 2 + (sig[1] * z[1]) ** 2 + 1e-30)


@pytest.mark.parametrize("spec", [3.7, 4.3])  # P_f = exp(-s^2/2): 1.1e-3 and 9.6e-5
@pytest.mark.parametrize("seed", [0, 1])
def test_importance_yield_on_a_circular_failure_region(spec, seed):
    exact = math.exp(-(spec**2) / 2)
    res = importance_yield(
        _rayleigh(SIG), 3, spec, key=jax.random.key(seed), n=4000,
        groups=[0, 1, 2], sigmas=SIG, names=("a", "b", "c"),
    )  # fmt: skip
    assert res.ok
    np.testing.assert_allclose(res.betas[0], spec, rtol=1e-4)  # FORM: beta = spec / sigma
    assert abs(res.failure_prob - exact) < 4 * res.failure_stderr
    assert res.failure_stderr < 0.2 * exact  # crude MC with 4,000 builds: > 40 %
    # likelihood-ratio gradient: dP/dsigma_a = dP/dsigma_b = s^2 exp(-s^2/2) / 2 at sigma = 1
    g_exact = spec**2 * exact / 2
    for k in (0, 1):
        assert abs(res.lr_gradient[k] - g_exact) < 4 * res.lr_gradient_stderr[k]
    assert abs(res.lr_gradient[2]) < 4 * res.lr_gradient_stderr[2] + 1e-12


def test_half_space_matches_form_exactly():
    a = jnp.array([0.6, 0.8, 0.0, 0.0])
    spec = 3.5
    res = importance_yield(lambda z: a @ z, 4, spec, key=jax.random.key(3), n=2000)
    exact = float(ndtr(-spec))
    np.testing.assert_allclose(res.form_failure_prob, exact, rtol=1e-6)
    np.testing.assert_allclose(res.design_points[0], spec * np.asarray(a), atol=1e-4)
    assert abs(res.failure_prob - exact) < 4 * res.failure_stderr
    assert res.failure_stderr < 0.05 * exact


def test_no_failure_within_reach_is_reported_not_estimated():
    res = importance_yield(lambda z: 1e-3 * jnp.sum(z**2), 3, 1.0, key=jax.random.key(0), n=100)
    assert res.status == "no_failure_found" and not res.ok
    assert "no start direction reached the spec" in res.message


def test_form_counts_its_evaluations():
    pts, betas, n_eval = form_design_points(_rayleigh(SIG), 3, 3.0, key=jax.random.key(0))
    assert pts.shape[1] == 3 and n_eval > 0
    np.testing.assert_allclose(betas, 3.0, rtol=1e-4)


def _train_values(n=2000):
    z = np.asarray(jax.random.normal(jax.random.key(9), (n, 2)))
    return lambda s: jnp.sqrt((s[0] * z[:, 0]) ** 2 + (s[1] * z[:, 1]) ** 2)


def _rare_metric(z, s):
    return jnp.sqrt((s[0] * z[0]) ** 2 + (s[1] * z[1]) ** 2 + 1e-30)


def test_allocate_reaches_a_9999_target_with_importance_sampling():
    from encdesign.design import allocate

    target = 0.9999
    res = allocate(
        _train_values(), [1.0, 1.0], ("a", "b"), 1.0, target,
        rare_metric=_rare_metric, rare_dim=2, rare_key=jax.random.key(4), rare_n=3000,
    )  # fmt: skip
    assert res.ok, res.message
    assert res.rare is not None and res.rare["yield"] - 2 * res.rare["yield_stderr"] >= target
    # independent check with the closed form of the (possibly unequal) Rayleigh failure:
    # crude Monte Carlo of 4e6 fresh builds
    zz = np.random.default_rng(0).normal(size=(4_000_000, 2))
    pf = np.mean((res.sigmas[0] * zz[:, 0]) ** 2 + (res.sigmas[1] * zz[:, 1]) ** 2 > 1.0)
    assert pf <= (1 - target) * 1.5  # IS meets the target, up to its own error
    # and it is not wasteful: the equal-sigma optimum has P_f = 1e-4 at sigma = 0.2330
    assert np.all(res.sigmas > 0.19)


def test_allocate_refuses_a_target_importance_sampling_cannot_reach():
    from encdesign import EncdesignInputError
    from encdesign.design import allocate

    def floor(z, s):  # a residual floor above the spec: no tolerance can fix it
        return jnp.sqrt((s[0] * z[0]) ** 2 + (s[1] * z[1]) ** 2 + 1.2**2)

    train = _train_values()
    with pytest.raises(EncdesignInputError, match=r"allocate.target.*unreachable"):
        allocate(
            lambda s: train(s) * 0 + 0.5, [1.0, 1.0], ("a", "b"), 1.0, 0.9999,
            rare_metric=floor, rare_dim=2, rare_key=jax.random.key(4), rare_n=500,
        )  # fmt: skip


def test_rare_event_result_renders_in_a_notebook():
    """``RareEventResult._repr_html_``: the status, P_f ± its error, FORM's estimate, the
    gradient per group, escaped."""
    from encdesign.design import DriverStatus, RareEventResult

    SUCCESS, NO_FAILURE_FOUND = DriverStatus.SUCCESS, DriverStatus.NO_FAILURE_FOUND

    r = RareEventResult(
        failure_prob=3.2e-7,
        failure_stderr=4.1e-8,
        n_builds=20_000,
        n_form_builds=312,
        design_points=np.zeros((2, 3)),
        betas=np.array([4.97, 5.3]),
        form_failure_prob=3.3e-7,
        lr_gradient=np.array([1.5e-3, -2.0e-4]),
        lr_gradient_stderr=np.array([1e-4, 3e-5]),
        names=("<runout>", "tilt"),
        n_failures=1234,
        defensive=0.1,
        wall_s=1.0,
        status=SUCCESS,
    )
    h = r._repr_html_()
    assert '<span class="badge ok">success</span>' in h
    assert "3.2e-07 ± 4.1e-08" in h and "<td>3.3e-07</td>" in h and "20000 / 312" in h
    assert "[4.97, 5.3]" in h and "<td>1234</td>" in h
    assert "<td>&lt;runout&gt;</td><td>0.0015</td><td>0.0001</td>" in h and "<runout>" not in h
    none = dataclasses.replace(r, status=NO_FAILURE_FOUND, message="P_f < 1e-9 & no start")
    h = none._repr_html_()
    assert "badge not-ok" in h and "P_f &lt; 1e-9 &amp; no start" in h
