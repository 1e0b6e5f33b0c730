"""Free head layouts: least-squares self-compensation for arbitrary azimuths (issue 14).

Checks the generalisation against closed forms and against Cramer's cotangent equations,
which are its N + 1 special case, then the Monte Carlo objective and its gradient, the
problem-file variable ``head_angles`` and its bad input, and the study ``head-layout-opt``.
"""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import encdesign
from encdesign import EncdesignInputError
from encdesign.design import parse_problem, solve_problem
from encdesign.objectives import (
    AbstractBuildDesign,
    EncoderDesign,
    LayoutDesign,
    Tolerances,
    build_metrics,
    layout_metrics,
    layout_residual,
    n_build_normals,
    symmetric_angles,
)
from encdesign.physics import (
    check_layout,
    cotangent_sensitivity,
    encoder_map,
    layout_map,
    layout_noise_amplification,
    least_squares_compensate,
    self_compensate,
    unobservable_orders,
)

M = 12
N_SAMPLES = 64


def _disk(seed: int, m: int = M):
    rng = np.random.default_rng(seed)
    return rng.normal(size=m) * 1e-6, rng.normal(size=m) * 1e-6


def _readings(angles, s, c, noise=0.0, seed=0):
    """Readings of heads at ``angles`` of the error ``e(theta - alpha_k)`` (plus constants
    and optional white noise), rad ``(n, H)``."""
    th = np.arange(N_SAMPLES) * 2 * np.pi / N_SAMPLES
    j = np.arange(1, s.size + 1)
    cols = []
    for k, a in enumerate(angles):
        arg = np.multiply.outer(th - a, j)
        cols.append(np.sin(arg) @ s + np.cos(arg) @ c + 1e-3 * k)
    y = np.stack(cols, axis=1)
    if noise:
        y = y + np.random.default_rng(seed).normal(size=y.shape) * noise
    return th, y


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("n_heads", [2, 3, 5])
def test_least_squares_recovers_the_disk_error_for_random_layouts(seed, n_heads):
    rng = np.random.default_rng(100 * seed + n_heads)
    angles = np.sort(rng.uniform(0, 2 * np.pi, n_heads))
    s, c = _disk(seed)
    th, y = _readings(angles, s, c)
    comp = least_squares_compensate(th, jnp.asarray(y), jnp.asarray(angles), M)
    assert unobservable_orders(angles, M) == []
    assert bool(jnp.all(comp.observable))
    np.testing.assert_allclose(comp.sin_rad, s, atol=1e-15)
    np.testing.assert_allclose(comp.cos_rad, c, atol=1e-15)
    assert float(jnp.max(comp.fit_residual_rad)) < 1e-15


@jax.jit  # one compile per head count, not one per operation (op by op: 16-55 compiles)
def _cotangent_and_layout_maps(th, y, angles, w):
    """Cramer's map of the ``N + 1`` layout and the least-squares map, at ``th``; the noise
    amplification of both (least squares: per order and aggregate; Cramer's: the same)."""
    n_sym = angles.shape[0] - 1
    cot = encoder_map(self_compensate(th, y, angles, n_sym, M), angles[:n_sym])
    ls = layout_map(least_squares_compensate(th, y, angles, M), w)
    amp, _, agg = layout_noise_amplification(angles, M, w)
    amp_c, agg_c = cotangent_sensitivity(angles[n_sym], symmetric_angles(n_sym), M)
    return ls(th), cot(th), (amp, agg, amp_c, agg_c)


@pytest.mark.parametrize("n_sym", [2, 3, 4])
@pytest.mark.parametrize("seed", [0, 7])
def test_cotangent_equations_are_the_n_plus_1_special_case(n_sym, seed):
    rng = np.random.default_rng(seed + 10 * n_sym)
    ref = rng.uniform(0.05, np.pi / n_sym - 0.05)
    angles = np.concatenate([np.asarray(symmetric_angles(n_sym)), [ref]])
    s, c = _disk(seed)
    w = np.r_[np.full(n_sym, 1.0 / n_sym), 0.0]  # Cramer averages the symmetric heads only
    for noise in (0.0, 1e-7):
        th, y = _readings(angles, s, c, noise=noise, seed=seed)
        ls, cot, amps = _cotangent_and_layout_maps(*map(jnp.asarray, (th, y, angles, w)))
        # with or without noise the two maps are the same linear function of the readings
        np.testing.assert_allclose(ls, cot, rtol=0, atol=1e-18)
    amp, agg, amp_c, agg_c = amps
    assert float(angles[n_sym]) == ref
    deg = np.arange(1, M + 1) % n_sym == 0
    np.testing.assert_allclose(np.asarray(amp)[deg], np.asarray(amp_c)[deg], rtol=1e-12)
    np.testing.assert_allclose(float(agg), float(agg_c), rtol=1e-12)
    # least squares uses every head difference: never noisier than the pairwise average
    assert np.all(np.asarray(amp) <= np.asarray(amp_c) * (1 + 1e-12))


def test_noise_amplification_matches_a_monte_carlo_of_read_noise():
    angles = np.radians([0.0, 71.0, 160.0, 250.0])
    s, c = np.zeros(M), np.zeros(M)
    sigma = 1e-6
    th = _readings(angles, s, c)[0]
    ys = np.stack([_readings(angles, s, c, noise=sigma, seed=seed)[1] for seed in range(400)])
    # the 400 draws in one vectorised call (same draws as one call per draw)
    est = jax.jit(jax.vmap(lambda y: least_squares_compensate(th, y, angles, M).sin_rad))
    ests = np.asarray(est(jnp.asarray(ys)))
    sigma_c = sigma * math.sqrt(2.0 / N_SAMPLES)  # std of one Fourier coefficient of noise
    measured = np.std(ests, axis=0) / sigma_c
    amp, _, _ = layout_noise_amplification(angles, M)
    # 400 draws: the sample std is within ~4 * 3.5 % of the truth
    np.testing.assert_allclose(measured, np.asarray(amp), rtol=0.15)


def test_unobservable_orders_and_their_noise():
    assert unobservable_orders(np.asarray(symmetric_angles(3)), 9) == [3, 6, 9]
    assert unobservable_orders(np.radians([0.0, 180.0]), 6) == [2, 4, 6]
    amp, gain, agg = layout_noise_amplification(jnp.radians(jnp.array([0.0, 180.0])), 6)
    assert np.all(np.isinf(np.asarray(amp)[1::2]))
    assert np.all(np.asarray(gain)[1::2] == 0.0)  # not in the map: no calibration noise
    assert math.isinf(float(agg))  # the output carries an order nobody can calibrate
    assert unobservable_orders(np.radians([0.0, 100.0, 230.0]), 16) == []


def _layout(angles, **kw):
    kw = {"max_order": 8, "grating_orders": 8, "n_angles": 64, "tilt_rad": 6e-3, **kw}
    return LayoutDesign(radius_m=0.0254, head_angles_rad=angles, **kw)


TOL = Tolerances(
    eccentricity=5e-6,
    tilt=1e-3,
    placement=2e-4,
    grating=5e-6,
    beam_tilt=1e-3,
    axial_runout=2e-6,
    noise=2e-7,
)


def test_layout_residual_equals_cramer_pipeline_on_the_n_plus_1_layout():
    ref = math.radians(18.09)
    cramer = EncoderDesign(
        radius_m=0.0254,
        reference_angle_rad=ref,
        tilt_rad=6e-3,
        n_heads=3,
        max_order=8,
        grating_orders=8,
        n_angles=64,
    )
    lay = _layout(cramer.head_angles_rad, weights=jnp.array([1.0, 1.0, 1.0, 0.0]))
    key = jax.random.key(3)
    # compiled: one program each (eagerly, every operation is a compile of its own)
    a = jax.jit(lambda k: build_metrics(cramer, TOL, key=k, n_builds=6))(key)
    b = jax.jit(lambda k: layout_metrics(lay, TOL, key=k, n_builds=6))(key)
    np.testing.assert_allclose(b, a, rtol=1e-10)


@pytest.mark.parametrize(
    "cls, heads",
    [
        (EncoderDesign, {"reference_angle_rad": 0.3157}),
        (LayoutDesign, {"head_angles_rad": [0.0, 2.1, 4.0]}),
    ],
)
def test_both_designs_share_the_geometry_and_its_checks(cls, heads):
    """The geometry, orders and sampling are declared and checked once
    (:class:`AbstractBuildDesign`); each design adds its heads."""
    d = cls(radius_m=0.02, **heads, max_order=4, grating_orders=5, axial_orders=1, n_angles=16)
    assert isinstance(d, AbstractBuildDesign)
    assert (float(d.tilt_rad), float(d.gap_m)) == (0.0, 1e-3)
    np.testing.assert_allclose(d.theta_rad, np.arange(16) * 2 * np.pi / 16)
    assert n_build_normals(d) == 2 + 2 + 2 * d.head_angles_rad.shape[0] + 2 * 5 + 2 * 1
    with pytest.raises(EncdesignInputError, match=rf"{cls.__name__}\.n_angles: 8 cannot resolve"):
        cls(radius_m=0.02, **heads, max_order=4, n_angles=8)
    with pytest.raises(EncdesignInputError, match=rf"{cls.__name__}\.radius_m: -0\.1, expected"):
        cls(radius_m=-0.1, **heads)
    with pytest.raises(EncdesignInputError, match=rf"{cls.__name__}: max_order, grating"):
        cls(radius_m=0.02, **heads, axial_orders=-1)
    with pytest.raises(TypeError):  # past the radius and the heads, keywords only
        cls(0.02, *heads.values(), 6e-3)


def test_problem_model_builds_both_designs_alike():
    """The registry builds either design from one set of a problem model's keys."""
    from encdesign.design._registry import _design_from, _geometry

    model = {
        "radius_m": 0.03, "tilt_rad": 2e-3, "gap_m": 5e-4, "n_heads": 4, "max_order": 6.0,
        "grating_orders": 7, "axial_orders": 1, "n_angles": 40,
    }  # fmt: skip
    enc = _design_from(model, 0.4)
    lay = LayoutDesign(head_angles_rad=enc.head_angles_rad, **_geometry(model))
    for d in (enc, lay):
        assert (float(d.radius_m), float(d.tilt_rad), float(d.gap_m)) == (0.03, 2e-3, 5e-4)
        assert (d.max_order, d.grating_orders, d.axial_orders, d.n_angles) == (6, 7, 1, 40)
        assert type(d.max_order) is int
    assert enc.n_heads == 4 and lay.n_heads == 5


def test_grating_only_build_is_compensated():
    lay = _layout(jnp.radians(jnp.array([0.0, 97.0, 211.0])))
    z = jax.random.normal(jax.random.key(0), (n_build_normals(lay),))
    r = jax.jit(layout_residual)(lay, Tolerances(grating=5e-6), z)  # eager: ~100 compiles
    assert float(jnp.max(jnp.abs(r))) < 1e-10  # 5 urad grating modes, removed to 2e-5


def test_layout_objective_gradient_matches_finite_differences():
    key = jax.random.key(1)

    def f(a):
        ms = layout_metrics(_layout(a, n_angles=32, max_order=4, grating_orders=4), TOL,
                            key=key, n_builds=4, metric="ms")  # fmt: skip
        return jnp.sqrt(jnp.mean(ms))

    # the values and the gradient from one compiled program (not one for f, one for its
    # gradient: CI time)
    f_and_g = jax.jit(jax.value_and_grad(f))
    a0 = np.radians([3.0, 100.0, 230.0, 300.0])
    g = np.asarray(f_and_g(jnp.asarray(a0))[1])
    h = 1e-4
    fd = [
        (float(f_and_g(jnp.asarray(a0 + h * e))[0]) - float(f_and_g(jnp.asarray(a0 - h * e))[0]))
        / (2 * h)
        for e in np.eye(a0.size)
    ]
    np.testing.assert_allclose(g, fd, rtol=1e-4)
    agg_and_g = jax.jit(jax.value_and_grad(lambda a: layout_noise_amplification(a, 8)[2]))
    agg, ga = agg_and_g(jnp.asarray(a0))
    ga = np.asarray(ga)
    fda = [
        (
            float(agg_and_g(jnp.asarray(a0 + h * e))[0])
            - float(agg_and_g(jnp.asarray(a0 - h * e))[0])
        )
        / (2 * h)
        for e in np.eye(a0.size)
    ]
    assert math.isfinite(float(agg))
    np.testing.assert_allclose(ga, fda, rtol=1e-5)


def test_coincident_heads_are_refused():
    with pytest.raises(EncdesignInputError, match="heads 0 and 2 coincide"):
        check_layout(np.radians([10.0, 100.0, 370.0]))
    with pytest.raises(ValueError, match="coincide"):
        _layout(jnp.radians(jnp.array([0.0, 0.0, 120.0])))


def _layout_problem(start, lower=-10.0, upper=370.0):
    return {
        "problem": {"name": "free", "objective": "head_layout"},
        "model": {"n_angles": 32, "max_order": 4, "grating_orders": 4, "n_builds": 4,
                  "sigma_placement": 1e-4, "sigma_grating": 5e-6, "sigma_noise": 2e-7},
        "variables": {"head_angles": {"units": "deg", "start": start, "lower": lower,
                                      "upper": upper}},
        "driver": {"kind": "bfgs", "max_steps": 30},
    }  # fmt: skip


def test_head_angles_bad_input_names_the_element():
    with pytest.raises(EncdesignInputError, match=r"variables\.head_angles\[2\]\.start.*400"):
        parse_problem(_layout_problem([0.0, 100.0, 400.0]), source="p.toml")
    with pytest.raises(EncdesignInputError, match=r"head_angles\.start.*heads 1 and 2 coincide"):
        parse_problem(_layout_problem([0.0, 100.0, 100.0]), source="p.toml")
    with pytest.raises(EncdesignInputError, match=r"head_angles\.lower: 2 values"):
        parse_problem(_layout_problem([0.0, 100.0, 200.0], lower=[0.0, 0.0]), source="p.toml")
    with pytest.raises(EncdesignInputError, match="outside the bounds"):
        parse_problem(_layout_problem([0.0, 100.0, 200.0], upper=150.0), source="p.toml")


def test_head_layout_problem_optimises_the_vector_variable():
    p = parse_problem(_layout_problem([0.0, 100.0, 250.0]), source="p.toml")
    assert [v.name for v in p.continuous] == ["head_angles[0]", "head_angles[1]",
                                              "head_angles[2]"]  # fmt: skip
    res = solve_problem(p)
    (r,) = res.results  # 30 BFGS steps: converged or stopped by the step limit
    assert r.status in ("success", "max_steps_reached"), r.message
    assert set(r.inputs) == {"head_angles[0]", "head_angles[1]", "head_angles[2]"}
    ev0 = jax.jit(p.objective.build(p, {}))(  # compiled: eagerly, seconds
        {"head_angles": jnp.radians(jnp.array([0.0, 100.0, 250.0]))}
    )
    assert r.outputs["residual_rms"] < 0.99 * float(ev0["residual_rms"])


def test_head_layout_study_quick(tmp_path):
    from encdesign.cli import main

    out = tmp_path / "hlo"
    rc = main(["study", "run", "head-layout-opt", "--quick", "--heads", "3", "--out", str(out),
               "--json", str(out / "s.json"), "--no-plots", "--fresh-builds", "4",
               "--max-steps", "6", "--n-angles", "16"])  # smaller than quick: CI time  # fmt: skip
    # (4 fresh builds, as many as the quick study's own: the fresh check reuses the
    # program of the study's builds, on its own key)
    assert rc == 0
    s = json.loads((out / "s.json").read_text())
    (h3,) = s["head_counts"]
    for which in ("optimum", "best_symmetric"):
        for k in ("head_angles_deg", "residual_urad", "noise_amplification"):
            assert k in h3[which]
        assert len(h3[which]["head_angles_deg"]) == 3
    assert h3["optimum"]["residual_urad"] <= h3["best_symmetric"]["residual_urad"] * (1 + 1e-12)
    assert h3["gradient_check"]["ok"]
    # out of sample (issue 27): both layouts on the same 4 fresh builds, a stated verdict
    assert s["n_fresh_builds"] == h3["n_fresh_builds"] == 4
    for which in ("optimum", "best_symmetric"):
        assert h3[which]["residual_urad_fresh"] > 0 and h3[which]["residual_urad_fresh_stderr"] > 0
        assert h3[which]["min_separation_deg"] >= 5.0 * (1 - 1e-6)
    assert isinstance(h3["win_significant"], bool) and h3["free_wins"] == h3["win_significant"]
    assert h3["verdict"] and s["wins_on_fresh_builds"]["3"] == h3["verdict"]
    if h3["fresh"] is not None:
        assert h3["fresh"]["n"] == 4 and h3["fresh"]["reduce"] == "rms"
    assert (
        encdesign.physics.unobservable_orders(np.radians(h3["optimum"]["head_angles_deg"]), 4) == []
    )
