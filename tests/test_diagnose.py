"""Discrepancy finder: effect terms, analytic Jacobian, recovery of each catalog effect,
clean recordings, refusal of malformed recordings, CLI and study."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import encdesign
from encdesign.cli import main as cli_main
from encdesign.diagnose import _effects as fx
from encdesign.diagnose import _multihead as D
from encdesign.diagnose._conceal import write_concealed
from tests.helpers import DIAGNOSE_TEST_AMPLITUDE, DIAGNOSE_TEST_SAMPLES_PER_RUN

SEED = {
    None: 11,
    "vibration": 1,
    "bearing_wobble": 2,
    "beam_tilt_axial": 3,
    "thermal_drift": 4,
    "interpolation_error": 5,
    "eccentricity_shift": 6,
}


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    root = tmp_path_factory.mktemp("diag")
    cache: dict = {}

    def get(effect):
        if effect not in cache:
            rec, truth = write_concealed(
                root / f"{effect}.toml",
                key=jax.random.key(SEED[effect]),
                effect=effect,
                samples_per_run=DIAGNOSE_TEST_SAMPLES_PER_RUN,
                amplitude=DIAGNOSE_TEST_AMPLITUDE,
                speeds_rev_s=(1.5, 2.5, 3.5),
            )
            cache[effect] = (rec, truth, encdesign.diagnose(rec))
        return cache[effect]

    return get


def _rel(a, b):
    return abs(a - b) / abs(b)


def test_interpolation_first_order_matches_arctangent():
    psi = jnp.linspace(0, 2 * jnp.pi, 257)[:, None]
    L = 1000
    o = jnp.array([1e-3]), jnp.array([-2e-3]), jnp.array([1.5e-3]), jnp.array([-1e-3])
    exact = fx.interpolation_error_exact_rad(psi / L, L, *o)
    coef = jnp.stack([o[0], -o[1], -o[3] / 2, -o[2] / 2])
    lin = fx.interpolation_harmonics_rad(psi, L, coef) + o[3] / 2 / L
    assert float(jnp.max(jnp.abs(exact - lin))) < 1e-2 * float(jnp.max(jnp.abs(exact)))


def test_wobble_cancels_in_opposed_heads_and_eccentricity_formula():
    th = jnp.linspace(0, 20, 400)
    al = jnp.array([0.3, 0.3 + jnp.pi])
    w = fx.bearing_wobble_rad(th, al, 0.02, 0.4, jnp.full(400, 1e-7), jnp.full(400, 2e-7))
    assert float(jnp.max(jnp.abs(w.sum(1)))) < 1e-18
    e = fx.eccentricity_rad(th, al, 0.02, 1e-6, 0.0)
    assert float(jnp.max(jnp.abs(e[:, 0] - 5e-5 * jnp.sin(th - 0.3)))) < 1e-18


def test_analytic_jacobian_matches_central_differences(bench):
    rec, _, _ = bench(None)
    prep = D.prepare(rec)
    lay = prep.layout
    rng = np.random.default_rng(0)
    p = rng.normal(size=lay.size + 1) * 1e-6
    p[prep.idx("d")] = 1e-3
    p[prep.idx("wb_nu")] = 0.4
    p[prep.idx("vb_f")] = 33.0
    p[prep.idx("es_t")] = prep.tau[prep.n // 2] + 0.3 * (prep.tau[1] - prep.tau[0])
    p[prep.idx("bt_beta")] = 0.01
    J = np.asarray(D._model_jac(jnp.asarray(p), prep.data, lay))
    f = jax.jit(lambda q: D._predict(q, prep.data, lay))
    picks = sorted(
        {s for s, _ in lay.segments.values()} | {s + n - 1 for s, n in lay.segments.values()}
    )
    for j in picks:
        h = 1e-5 * max(abs(p[j]), 1e-3)
        q1, q2 = p.copy(), p.copy()
        q1[j] += h
        q2[j] -= h
        fd = (np.asarray(f(jnp.asarray(q1))) - np.asarray(f(jnp.asarray(q2)))) / (2 * h)
        scale = max(float(np.max(np.abs(fd))), 1e-30)
        assert np.max(np.abs(fd - J[:, :, j])) < 1e-4 * scale, j


def test_clean_recording_is_consistent(bench):
    _, _, d = bench(None)
    assert d.verdict == "consistent", (d.unexplained, d.rejected)
    assert not d.effects and not d.unexplained
    assert d.heldout_rms_before < 1.2 * np.mean(d.noise_rad)
    assert d.base["disk_eccentricity_m_se"][0] > 0


@pytest.mark.parametrize("effect", list(fx.CATALOG_MULTIHEAD))
def test_each_effect_is_named_and_recovered(bench, effect):
    _, truth, d = bench(effect)
    assert d.verdict == "missing_physics", (d.rejected, d.unexplained)
    assert d.effects[0].name == effect
    assert d.heldout_rms_final < d.heldout_rms_before
    got, tp = d.effects[0].params, truth["params"]
    if effect == "vibration":
        assert _rel(got["frequency_hz"], tp["frequency_hz"]) < 0.1
        a, b = np.asarray(got["amplitude_rad_per_head"]), np.asarray(tp["amplitude_rad_per_head"])
        assert np.all(np.abs(a - b) < 0.1 * b)
    elif effect == "bearing_wobble":
        assert _rel(got["frequency_ratio"], tp["frequency_ratio"]) < 0.1
        assert _rel(got["runout_m"], tp["runout_m"]) < 0.1
    elif effect == "beam_tilt_axial":
        m = tp["runout_orders"][0]
        col = got["runout_orders"].index(m)
        a = np.asarray(got["error_amplitude_rad"])[:, col]
        b = np.asarray(tp["error_amplitude_rad"])
        big = b > 0.3 * b.max()
        assert np.all(np.abs(a - b)[big] < 0.1 * b[big])
    elif effect == "thermal_drift":
        a, b = np.asarray(got["rate_rad_per_k"]), np.asarray(tp["rate_rad_per_k"])
        big = np.abs(b) > 0.3 * np.abs(b).max()
        assert np.all(np.abs(a - b)[big] < 0.1 * np.abs(b)[big])
    elif effect == "interpolation_error":
        a = np.asarray(got["amplitude_1x_pitch_rad"])
        b = np.hypot(tp["offset_a"], tp["offset_b"]) / got["grating_lines"]
        assert np.all(np.abs(a - b) < 0.1 * b)
    elif effect == "eccentricity_shift":
        assert _rel(got["shift_m"], tp["shift_m"]) < 0.1
        assert got["shift_run"] == tp["shift_run"]
        assert _rel(got["shift_time_s"], tp["shift_time_s"]) < 0.1


def test_refuses_malformed_recordings(tmp_path):
    n = 100
    cols = {"t": np.arange(n) * 0.01, "h0": np.linspace(0, 1, n), "h1": np.linspace(0, 1, n)}
    enc = dict(optical_radius_m=0.02, head_angles_deg=[0.0, 180.0])
    rec = encdesign.write_recording(tmp_path / "short.toml", "multihead", cols, encoder=enc)
    with pytest.raises(encdesign.EncdesignInputError, match="samples"):
        encdesign.diagnose(rec)
    qrec = encdesign.write_recording(
        tmp_path / "q.toml", "quadrature", {"sa": [0.0, 1.0], "sb": [1.0, 0.0]}
    )
    with pytest.raises(encdesign.EncdesignInputError, match="kind"):
        encdesign.diagnose(qrec)
    # less than a revolution
    m = 400
    cols = {"t": np.arange(m) * 0.01, "h0": np.linspace(0, 1, m), "h1": np.linspace(0, 1, m)}
    rec = encdesign.write_recording(tmp_path / "part.toml", "multihead", cols, encoder=enc)
    with pytest.raises(encdesign.EncdesignInputError, match="revolution"):
        encdesign.diagnose(rec)
    # the CLI: bad recordings exit 2 with a message
    (tmp_path / "bad.toml").write_text('format = "encdesign-recording/1"\nkind = "multihead"\n')
    assert (
        cli_main(["diagnose", str(tmp_path / "bad.toml"), "--json", str(tmp_path / "o.json")]) == 2
    )
    assert not (tmp_path / "o.json").exists()


def test_cli_writes_json_contract(bench, tmp_path, capsys):
    rec, _, _ = bench("vibration")
    out = tmp_path / "d.json"
    rc = cli_main(
        ["diagnose", str(rec.path), "--json", str(out), "--plots", str(tmp_path / "p"), "--quiet"]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    for key in ("verdict", "rms_before", "heldout_rms_before", "effects", "unexplained"):
        assert key in doc
    e = doc["effects"][0]
    assert {"name", "params", "rms_after", "heldout_rms_after", "explanation"} <= set(e)
    assert e["name"] == "vibration" and doc["verdict"] == "missing_physics"
    assert len(list((tmp_path / "p").glob("*.png"))) == 3
    assert "verdict: missing_physics" in capsys.readouterr().out


def test_conceal_benchmark_study_quick(tmp_path):
    out = tmp_path / "bench"
    rc = cli_main(
        [
            "study",
            "run",
            "conceal-benchmark",
            "--quick",
            "--out",
            str(out),
            "--json",
            str(tmp_path / "s.json"),
            "--no-plots",
        ]
    )
    assert rc == 0
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["n_recordings"] == 3
    assert s["clean_no_claim_pct"] == 100.0
    assert s["per_effect_correct_pct"]["vibration"] == 100.0
    assert s["per_effect_correct_pct"]["count_jump"] == 100.0


def test_diagnose_example_study_quick(tmp_path):
    out = tmp_path / "ex"
    rc = cli_main(["study", "run", "diagnose-example", "--quick", "--out", str(out)])
    assert rc == 0
    s = json.loads((out / "diagnose-example.json").read_text())
    assert s["diagnosis"]["verdict"] == "missing_physics"
    assert s["diagnosis"]["effects"][0]["name"] == "vibration"
    assert (out / "residual_spectra.png").exists() and (out / "report.txt").exists()
