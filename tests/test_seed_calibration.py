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


@pytest.mark.parametrize("which", ["device1", "device2", "shaker"])
def test_fit_gradients_match_finite_differences(which):
    import jax

    m = _study()
    if which == "device1":
        inst = m.device1(_coef(), {"mean_arcsec": -3.0, "std_arcsec": 2.0}, jax.random.PRNGKey(3))
    elif which == "device2":
        inst = m.device2((0.05, 0.03))
    else:
        inst = m.shaker()
    w = np.ones(sum(f.role == "train" for f in inst.figures))
    resid = m.training_residuals(inst, w)
    th = jnp.asarray(inst.theta0, float) + 0.1
    jac = np.asarray(jax.jacfwd(resid)(th))
    h = 1e-6
    for i in range(th.size):
        e = jnp.zeros_like(th).at[i].set(h)
        fd = (np.asarray(resid(th + e)) - np.asarray(resid(th - e))) / (2 * h)
        np.testing.assert_allclose(jac[:, i], fd, rtol=1e-5, atol=1e-7)


def test_shaker_fit_recovers_training_figures():
    m = _study()
    res = m.fit(m.shaker())
    assert res["status"] == "success"
    assert res["chi2_training"] < 1e-6
    offsets = [p["value"] for p in res["params"] if p["name"].startswith("f_exc_offset")]
    assert all(0.0 < x < 0.5 for x in offsets)


def test_study_seed_calibration_quick(tmp_path, monkeypatch):
    """The study end to end (fits, predictions, tension, JSON, plot) with the simulated noise
    coefficients and pair constants replaced by stand-ins: the simulations are
    ``simulate_readings`` (tested in ``test_sds.py``) and cost most of the run's compiling;
    the pair constants' library function is tested above."""
    m = _study()
    monkeypatch.setattr(m, "sds_noise_coefficients", lambda marks, n_revs, key: _coef())
    monkeypatch.setattr(
        m, "pair_offset_constants", lambda marks, p: {"mean_arcsec": -3.0, "std_arcsec": 2.0}
    )
    out = tmp_path / "sc"
    assert m.main(["--quick", "--out", str(out), "--json", str(out / "s.json")]) == 0
    res = json.loads((out / "s.json").read_text())
    assert any(out.glob("*.png"))
    assert len(res["instruments"]) == 3
    for r in res["instruments"]:
        assert r["chi2_training"] >= 0 and r["predicted_total"] > 0
        assert r["tension_all_figures"]["dof"] >= 1
    assert res["predicted_total"] >= res["predicted_within_2sigma"]
    assert res["closed_forms"]["s001_closure_counts"]["N72_23_settings"]["n_equations"] == 1658


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
