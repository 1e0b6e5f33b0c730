"""The seed-calibration study: fit gradients against finite differences, and a --quick run."""

import importlib.util
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

_PATH = Path(__file__).resolve().parents[1] / "studies" / "seed_calibration.py"


def _study():
    spec = importlib.util.spec_from_file_location("seed_calibration_under_test", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _coef():
    return {
        "marks": 100,
        "whirl_one_pp_fig9_arcsec_per_um": 0.6,
        "whirl_two_pp_fig9_arcsec_per_um": 0.017,
        "whirl_two_std_mas_per_um": 3.0,
        "whirl_two_maxabs_long_mas_per_um": 10.0,
        "jitter_one_std_mas_per_ns": 0.18,
        "jitter_two_std_mas_per_ns": 0.13,
    }


def _device1(m):
    import jax

    return m.device1(
        _coef(),
        {"mean_arcsec": -3.0, "std_arcsec": 2.0},
        jax.random.PRNGKey(3),
        tir_per_rms=4.7,
        n_draw=50,
    )


@pytest.mark.parametrize(
    "which", ["device1", "device2", "shaker", "shaker-proportional", "shaker-per-case"]
)
def test_fit_gradients_match_finite_differences(which):
    """The Jacobian of every instrument's residuals (JAX) against central differences, at a
    point off the fit, for every physical unknown (whirl, jitter, drift, placement, speed ×
    marks, axial runout, vibration amplitudes, FFT offset, speed exponent)."""
    import jax

    m = _study()
    inst = {
        "device1": lambda: _device1(m),
        "device2": m.device2,
        "shaker": m.shaker,
        "shaker-proportional": lambda: m.shaker(True, "proportional"),
        "shaker-per-case": lambda: m.shaker(False, "per_case"),
    }[which]()
    w = np.ones(sum(f.kind == "train" for f in inst.figures))
    resid = m.training_residuals(inst, w)
    th = jnp.asarray([p.x0 for p in inst.params], float) * 1.1 + 0.01
    jac = np.asarray(jax.jacfwd(resid)(th))
    assert np.all(np.any(jac != 0, axis=0)), "a parameter no training figure sees"
    for i in range(th.size):
        h = 1e-6 * max(1.0, abs(float(th[i])))
        e = jnp.zeros_like(th).at[i].set(h)
        fd = (np.asarray(resid(th + e)) - np.asarray(resid(th - e))) / (2 * h)
        np.testing.assert_allclose(jac[:, i], fd, rtol=1e-5, atol=1e-6)


def test_agreement_rule_bound_is_a_bound_not_a_gaussian():
    """A value agrees within 2σ (seed and model σ combined); a bound is met when the model
    minus 2 σ_model is below it, whatever σ the seed's digits would suggest."""
    m = _study()
    # today's row 1.32 (before issue 42): 38.8 ± 3.1 mas against "did not exceed 32 mas"
    assert not m.agreement(38.8, 3.1, 32.0, 3.2, "upper")["agrees"]
    assert m.agreement(38.8, 3.1, 32.0, 3.2, None)["agrees"]  # the old Gaussian reading
    assert m.agreement(30.0, 1.0, 32.0, 0.0, "upper")["agrees"]
    assert m.agreement(33.0, 1.0, 32.0, 0.0, "upper")["agrees"]
    assert not m.agreement(34.5, 1.0, 32.0, 0.0, "upper")["agrees"]
    # today's row 1.57: z +2.3 is outside 2σ
    assert not m.agreement(0.122, 0.013, 0.05, 0.03 * 0 + 0.0257, None)["agrees"]
    z = m.agreement(1.0, 0.3, 0.0, 0.4, None)
    assert z["agrees"] and z["residual_sigma"] == pytest.approx(2.0)


def test_shaker_fit_is_a_test_and_predicts_the_fast_case():
    """The seed-002 shaker: 5 physical unknowns on 7 figures (χ² with 2 dof); the model
    before issue 42 (no speed dependence, one FFT offset per case) is exactly determined;
    the 3.4 mm/s compensated peak, not fitted, comes out within 2σ of the seed's 1.0 µm."""
    m = _study()
    res = m.fit(m.shaker())
    assert res["status"] == "success" and res["n_unknowns"] == 5 and res["dof"] == 2
    assert 0.05 < res["p_value"] < 1.0
    fig = {x["key"]: x for x in res["figures"]}
    assert fig["700Hz_3.4_before"]["kind"] == "train"
    after = fig["700Hz_3.4_after"]
    assert after["kind"] == "predict" and after["agrees"]
    assert 0.8 < after["model"] < 1.1
    assert not fig["area_worst"]["agrees"]  # the seed's ~50 % stays a miss
    gamma = next(p for p in res["unknowns"] if p["name"] == "speed_exponent")
    assert 0.05 < gamma["value"] < 0.3 and gamma["se"] > 0
    old = m.fit(m.shaker(False, "per_case"))
    assert old["test"] == "exactly determined: no test" and old["predicted_total"] == 0
    assert old["chi2_training"] < 1e-8
    oldfig = {x["key"]: x for x in old["figures"]}
    assert not oldfig["700Hz_3.4_before"]["agrees"] and not oldfig["700Hz_3.4_after"]["agrees"]


def test_ramp_draws_have_the_random_walk_residual_variance():
    """A unit random walk about its least-squares line keeps 1/15 of its end variance on
    average (the closed form the derived drift share uses); a half-sine bow keeps an RMS
    of 0.31 of its amplitude about its line."""
    import jax

    rd = _study().ramp_draws(jax.random.PRNGKey(5), n_draw=800, n_t=256)
    assert np.mean(rd["walk"] ** 2) == pytest.approx(1 / 15, rel=0.05)
    assert np.abs(rd["bow_amp"]).max() <= 1.0
    assert np.sqrt(np.mean(rd["bow"] ** 2)) == pytest.approx(0.31, abs=0.01)


def test_eq5_gives_the_peak_no_speed_dependence():
    """Seed 002's eq. 5 on one channel: the peak position error is the same at 0.8, 2 and
    3.4 mm/s (so the seed's 1.5 -> 1.8 µm needs another cause: the fitted exponent); on both
    channels it is an amplitude modulation with no position error at all."""
    r = _study().eq5_speed_ratio()
    assert r["peak_ratio_3.4_over_0.8_one_channel"] == pytest.approx(1.0, abs=0.01)
    assert min(r["one_channel"]["peak_um"].values()) > 0.05
    assert max(r["both_channels"]["peak_um"].values()) < 1e-9


def test_study_seed_calibration_quick(tmp_path, monkeypatch):
    """The study end to end (fits, predictions, variants, JSON, plot) with the simulated noise
    coefficients and pair constants replaced by stand-ins: the simulations are
    ``simulate_readings`` (tested in ``test_sds.py``) and cost most of the run's compiling;
    the pair constants' library function is tested below."""
    m = _study()
    monkeypatch.setattr(m, "sds_noise_coefficients", lambda marks, n_revs, key: _coef())
    monkeypatch.setattr(
        m, "pair_offset_constants", lambda marks, p: {"mean_arcsec": -3.0, "std_arcsec": 2.0}
    )
    out = tmp_path / "sc"
    assert m.main(["--quick", "--out", str(out), "--json", str(out / "s.json")]) == 0
    res = json.loads((out / "s.json").read_text())
    assert any(out.glob("*.png"))
    inst = {r["instrument"]: r for r in res["instruments"]}
    assert set(inst) == {"seed001-device1", "seed001-device2", "seed002-shaker"}
    d1, d2 = inst["seed001-device1"], inst["seed001-device2"]
    assert d1["n_unknowns"] == 6 and d1["n_training"] == 7 and d1["dof"] == 1
    assert d1["p_value"] is not None and 0.0 <= d1["p_value"] <= 1.0
    assert d2["test"] == "exactly determined: no test" and d2["predicted_total"] == 0
    assert d2["p_value"] is None
    fig = {x["key"]: x for x in d1["figures"]}
    # the training figures are reproduced (the seed's numbers, not only χ² ≥ 0)
    for k, v in [("fig9_one_pair_pp", 0.42), ("fig12_rms_min", 8.0), ("fig12_rms_max", 15.3)]:
        assert fig[k]["kind"] == "train" and abs(fig[k]["model"] - v) < 0.2 * v
    # not predictions: fig. 10 is a constant, the inch a conversion, fig. 15 a bound
    assert fig["fig10_step_detected"]["kind"] == "constant"
    assert fig["pair_offset_inch"]["kind"] == "conversion"
    assert fig["fig15_instrument_rms"]["kind"] == "bound"
    assert fig["whirl_tir_vs_spec"]["kind"] == "hypothesis"
    for r in res["instruments"]:
        counted = [x for x in r["predictions"] if "agrees" in x] if r["dof"] > 0 else []
        assert r["predicted_total"] == len(counted)
        assert r["predicted_within_2sigma"] == sum(x["agrees"] for x in counted)
        for k in ("constant", "conversion", "bound", "hypothesis"):
            assert all(x["kind"] == k for x in r["separate"][k])
    assert res["predicted_total"] == sum(r["predicted_total"] for r in res["instruments"])
    assert res["predicted_total"] == 7
    assert res["predicted_within_2sigma"] == sum(
        r["predicted_within_2sigma"] for r in res["instruments"]
    )
    assert res["closed_forms"]["s001_closure_counts"]["N72_23_settings"]["n_equations"] == 1658
    assert res["eq5_speed_check"]["peak_ratio_3.4_over_0.8_one_channel"] == pytest.approx(
        1, abs=0.01
    )


def _instrument_tests_study():
    path = _PATH.parent / "sds_instrument_tests.py"
    spec = importlib.util.spec_from_file_location("sds_instrument_tests_under_test", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _pair_offset_oracle(design, offset_rad, phis, errors):
    """The computation both studies wrote out before it moved to the library."""
    import encdesign as ed

    az = np.asarray(design.moving_azimuths_rad).copy()
    az[1] += offset_rad
    moved = ed.SDSDesign(
        design.motor,
        design.disk_a,
        design.disk_b,
        design.fixed_azimuths_rad,
        jnp.asarray(az),
        design.radius_m,
    )
    dz = np.asarray(moved.zero_offsets_rad() - design.zero_offsets_rad())
    out = []
    for phi in phis:
        r = ed.simulate_readings(moved, float(phi), 1, errors)
        pair = np.asarray(r.pair_error_rad)[0] + dz
        out.append(float(pair[1, 1] - pair[0, 0]))
    return np.array(out)


def test_pair_offset_library_function_reproduces_the_studies_computation():
    """``physics.moved_sensor_pair_errors`` gives, bit for bit, what both studies computed
    before it moved to the library (one platform angle, 100 edges: the cost is compiling)."""
    import encdesign as ed
    from encdesign.physics import ARCSEC

    phis = np.deg2rad([107.0])
    design = ed.reference_design(2, 2, marks_per_rev=100)
    errors = _study()._quiet_errors()
    lib = np.asarray(ed.physics.moved_sensor_pair_errors(design, 1, 89.5 * ARCSEC, phis, errors))
    assert lib.shape == (1, 2, 2)
    want = _pair_offset_oracle(design, 89.5 * ARCSEC, phis, errors)
    np.testing.assert_array_equal(lib[:, 1, 1] - lib[:, 0, 0], want)
    # the offset is the placement plus the pairs' systematic constants (a few arcsec)
    assert abs(float(want[0]) / ARCSEC - 89.5) < 15.0
    with pytest.raises(ed.EncdesignInputError, match="sensor"):
        ed.physics.moved_sensor_pair_errors(design, 2, 0.0, phis)


def test_both_studies_take_the_pair_offset_from_the_library(monkeypatch):
    """Both studies read the pair offset from ``moved_sensor_pair_errors`` (a stand-in
    with known pair errors: no simulation), each with its own error physics."""
    import encdesign as ed
    from encdesign.physics import ARCSEC

    calls = []

    def fake(design, sensor, offset_rad, phis_rad, errors=None):
        calls.append((sensor, offset_rad, errors))
        n = len(np.atleast_1d(phis_rad))
        e = np.zeros((n, 2, 2))
        e[:, 1, 1] = offset_rad + np.arange(n) * ARCSEC
        return jnp.asarray(e)

    monkeypatch.setattr(ed.physics, "moved_sensor_pair_errors", fake)
    sc, it = _study(), _instrument_tests_study()
    got = sc.pair_offset_constants(100, 89.5)
    np.testing.assert_allclose(got["values"], [0.0, 1.0, 2.0, 3.0], atol=1e-9)
    phis = np.deg2rad([10.0, 20.0])
    got = it.pair_offset(ed.reference_design(2, 2, marks_per_rev=100), 89.5, phis)
    np.testing.assert_allclose(got["pair_offset_arcsec"], [89.5, 90.5], atol=1e-9)
    assert [c[:2] for c in calls] == [(1, 89.5 * ARCSEC)] * 2
    assert calls[0][2] is not None and calls[1][2] is not None
