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


def test_study_seed_calibration_quick(tmp_path):
    from encdesign.cli import main

    out = tmp_path / "sc"
    assert (
        main(
            [
                "study",
                "run",
                "seed-calibration",
                "--quick",
                "--out",
                str(out),
                "--json",
                str(out / "s.json"),
            ]
        )
        == 0
    )
    res = json.loads((out / "s.json").read_text())
    assert any(out.glob("*.png"))
    assert len(res["instruments"]) == 3
    for r in res["instruments"]:
        assert r["chi2_training"] >= 0 and r["predicted_total"] > 0
    assert res["predicted_total"] >= res["predicted_within_2sigma"]
