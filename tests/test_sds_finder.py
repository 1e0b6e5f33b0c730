"""Discrepancy finder for sds recordings (``encdesign.diagnose._sds``)."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import encdesign  # noqa: F401  (float64)
from encdesign.cli import main as cli_main
from encdesign.diagnose._conceal_sds import write_concealed_sds
from encdesign.diagnose._sds import _Fitter, diagnose_sds, sds_pair_table, sds_terms
from encdesign.io._recording import load_recording, write_recording

N_RUNS = 12  # platform positions per test recording (as in the benchmark)


@pytest.fixture(scope="module")
def sds_bench(tmp_path_factory):
    """Write (once per effect) a test recording with an effect at a clear amplitude."""
    cache: dict = {}
    folder = tmp_path_factory.mktemp("sds")

    def make(effect, concealment="clear", phi_ref=True):
        k = (effect, concealment, phi_ref)
        if k not in cache:
            path = folder / f"{effect}-{concealment}-{int(phi_ref)}.toml"
            cache[k] = write_concealed_sds(
                path,
                key=jax.random.key(7),
                effect=effect,
                concealment=concealment,
                phi_ref=phi_ref,
                n_runs=N_RUNS,
            )
        return cache[k]

    return make


def _param(d, name, key):
    e = next(e for e in d["effects"] if e["name"] == name)
    return e["params"][key]["value"]


def test_clean_recording_is_consistent(sds_bench):
    rec, _ = sds_bench(None)
    d = diagnose_sds(rec)
    assert d["verdict"] == "consistent", d["report"]
    assert d["effects"] == [] and d["unexplained"] == []
    assert d["heldout_rms_before"] > 0 and d["rms_before"] > 0
    assert any("constant offset" in u for u in d["base"]["unidentifiable"])


@pytest.mark.parametrize(
    "effect, key, truth_key",
    [
        ("axis_tilt", "tilt_rad", "tilt_rad"),
        ("thermal_drift", "drift_rate_rad_per_s", "drift_rate_rad_per_s"),
        ("bearing_wobble", "amplitude_rad", "amplitude_rad"),
    ],
)
def test_effect_named_and_recovered(sds_bench, effect, key, truth_key):
    rec, truth = sds_bench(effect)
    d = diagnose_sds(rec)
    assert d["verdict"] == "missing_physics", d["report"]
    assert d["effects"][0]["name"] == effect, d["report"]
    got = _param(d, effect, key)
    want = truth["params"][truth_key]
    assert abs(abs(got) - want) < 0.1 * want, (got, want)
    e = d["effects"][0]
    assert e["heldout_rms_after"] < d["heldout_rms_before"]
    assert e["explanation"]


def test_beam_tilt_named_and_recovered(sds_bench):
    rec, truth = sds_bench("beam_tilt_axial")
    d = diagnose_sds(rec)
    assert d["effects"][0]["name"] == "beam_tilt_axial", d["report"]
    p = d["effects"][0]["params"]
    got = p["order_1"]["error_amplitude_rad"]["value"]
    want = truth["params"]["order_1_amplitude_rad"]
    assert abs(got - want) < 0.1 * want


def test_coil_mismatch_named_and_speed_ripple_recovered(sds_bench):
    rec, truth = sds_bench("coil_mismatch")
    d = diagnose_sds(rec)
    assert d["effects"][0]["name"] == "coil_mismatch", d["report"]
    got = d["effects"][0]["params"]["speed_ripple_relative"]["order_1"]["value"]
    want = truth["params"]["speed_ripple_order_1"]
    assert abs(got - want) < 0.1 * want


def test_timing_quantization_named(sds_bench):
    rec, truth = sds_bench("timing_quantization")
    d = diagnose_sds(rec)
    names = [e["name"] for e in d["effects"]]
    assert "timing_quantization" in names, d["report"]
    got = _param(d, "timing_quantization", "clock_period_s")
    assert abs(got - truth["params"]["clock_period_s"]) < 0.1 * truth["params"]["clock_period_s"]


def test_out_of_catalog_is_unexplained(tmp_path):
    rec, _ = write_concealed_sds(
        tmp_path / "o5.toml", key=jax.random.key(7), effect="order_5", concealment="clear"
    )  # 12 runs: order 5 must not alias onto the candidates' orders 1-3
    d = diagnose_sds(rec)
    assert d["verdict"] == "unexplained", d["report"]
    assert any(5 in u["where"]["orders"] for u in d["unexplained"])


def test_candidate_term_gradients_match_finite_differences(sds_bench):
    rec, _ = sds_bench(None)
    tab = sds_pair_table(rec)
    f = _Fitter(tab, [6], (1, 2))
    lay = f.layout
    p = np.zeros(lay.size)
    p[lay.sl("axis_tilt")] = [1e-3, 0.4]
    p[lay.sl("bearing_wobble")] = [0.41, 3e-7, -2e-7]
    p[lay.sl("thermal_drift")] = [1e-8]
    p[lay.sl("beam_tilt_axial")] = 1e-7
    p[lay.sl("coil_mismatch")] = 5e-8
    w = jnp.asarray(np.random.default_rng(0).normal(size=tab.value_rad.size))

    def obj(q):
        terms = sds_terms(q, f.data, lay)
        return 1e6 * sum(jnp.dot(w, terms[k]) for k in terms if k not in ("pair_const",))

    g = np.asarray(jax.grad(obj)(jnp.asarray(p)))
    for idx in [lay.sl("axis_tilt").start, lay.sl("axis_tilt").start + 1]:
        h = 1e-5
        for i, hh in ((idx, h), (lay.sl("bearing_wobble").start, 1e-6)):
            e = np.zeros_like(p)
            e[i] = hh
            fd = (float(obj(jnp.asarray(p + e))) - float(obj(jnp.asarray(p - e)))) / (2 * hh)
            assert abs(g[i] - fd) <= 1e-4 * max(abs(fd), 1e-3), (i, g[i], fd)


def test_cli_sds_contract_and_refusal(sds_bench, tmp_path, capsys):
    rec, _ = sds_bench("thermal_drift")
    out = tmp_path / "d.json"
    rc = cli_main(["diagnose", str(rec.path), "--json", str(out), "--plots", str(tmp_path / "p")])
    assert rc == 0
    doc = json.loads(out.read_text())
    for key in ("verdict", "rms_before", "heldout_rms_before", "effects", "unexplained"):
        assert key in doc
    assert {"name", "params", "rms_after", "heldout_rms_after", "explanation"} <= set(
        doc["effects"][0]
    )
    assert len(list((tmp_path / "p").glob("*.png"))) == 3
    # malformed: a missing edge in one sensor's sequence -> exit 2, clear message
    full = load_recording(rec.path)
    data = [p for p in rec.path.parent.glob(rec.path.stem + "*") if p.suffix != ".toml"][0]
    lines = data.read_text().splitlines(keepends=True)
    m1 = [i for i, line in enumerate(lines) if ",m1," in line]
    (tmp_path / rec.path.name).write_text(rec.path.read_text())
    (tmp_path / data.name).write_text("".join(lines[: m1[100]] + lines[m1[100] + 1 :]))
    capsys.readouterr()
    rc = cli_main(["diagnose", str(tmp_path / rec.path.name), "--json", str(tmp_path / "b.json")])
    assert rc == 2
    assert "missing" in capsys.readouterr().err
    assert not (tmp_path / "b.json").exists()
    cols = {k: np.asarray(v) for k, v in full.columns.items()}
    # too few runs
    few = {k: v[cols["run"] < 2] for k, v in cols.items()}
    rec2 = write_recording(tmp_path / "few.toml", "sds", few, encoder=full.encoder)
    with pytest.raises(encdesign.EncdesignInputError, match="runs"):
        diagnose_sds(rec2)


def test_readings_windows_aligned_in_time(sds_bench):
    """Every reading's windows cover the same revolution: a wobble that changes from one
    revolution to the next gives no bias in the first reading of a run (it gave ~300 nrad
    when late-starting sensors read a window one revolution later)."""
    from encdesign.io._sds_recording import sds_readings_from_recording

    rec, truth = sds_bench("bearing_wobble")
    res = sds_readings_from_recording(rec)
    first = np.asarray([r[0] for r in res.readings_rad])
    rest = np.asarray([np.median(r[1:]) for r in res.readings_rad])
    dev = np.mod(first - rest + np.pi, 2 * np.pi) - np.pi
    assert truth["params"]["amplitude_rad"] > 3e-7
    assert np.max(np.abs(dev)) < 6e-8, dev


def test_common_only_coil_order_is_unidentifiable_without_phi_ref(sds_bench):
    rec, _ = sds_bench("coil_mismatch", "clear", False)
    d = diagnose_sds(rec)
    assert d["effects"][0]["name"] == "coil_mismatch", d["report"]
    # three equally spaced moving sensors: order 3 has one phase at all of them
    assert any("orders [3]" in u for u in d["base"]["unidentifiable"]), d["report"]


def test_optical_radius_from_the_recording(sds_bench, tmp_path):
    rec, _ = sds_bench("bearing_wobble")
    base = diagnose_sds(rec)
    enc = dict(rec.encoder, optical_radius_m=0.05)
    path = tmp_path / "r.toml"
    write_recording(path, "sds", dict(rec.columns), encoder=enc)
    d = diagnose_sds(load_recording(path))
    assert base["base"]["radius_m"] == pytest.approx(0.0254)
    assert d["base"]["radius_m"] == pytest.approx(0.05)
    bad = tmp_path / "bad.toml"
    with pytest.raises(encdesign.EncdesignInputError, match="optical_radius_m"):
        write_recording(bad, "sds", dict(rec.columns), encoder=dict(enc, optical_radius_m=-1.0))
    assert not bad.exists()
    text = path.read_text().replace("optical_radius_m = 0.05", "optical_radius_m = -1.0")
    bad.write_text(text)
    with pytest.raises(encdesign.EncdesignInputError, match="optical_radius_m"):
        load_recording(bad)
