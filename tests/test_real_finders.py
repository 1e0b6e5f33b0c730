"""Finders of the real-data kinds (motion, quadrature): synthetic truth, then shipped data."""

from pathlib import Path

import numpy as np
import pytest

from encdesign import write_recording
from encdesign.cli import main
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose._motion import candidate_orders
from encdesign.diagnose._quadrature import diagnose_quadrature
from tests.helpers import validate_diagnosis

DATA = Path(__file__).resolve().parent.parent / "data" / "real"


def _motion(tmp_path, ripple: dict[int, float], noise_rad=2e-4, seed=0):
    """One turn at 0.6 rad/s; ``ripple``: order -> relative speed ripple."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0, 10.0, 3000))
    omega = 2 * np.pi / 10.2
    theta = omega * t
    for _ in range(3):  # angle ripple r/m at order m, as a function of the angle itself
        theta = omega * t + sum(r / m * np.sin(m * theta + 0.3 * m) for m, r in ripple.items())
    theta = theta + rng.normal(0, noise_rad, t.size)
    return write_recording(
        tmp_path / "m.toml",
        "motion",
        {"t": t, "theta": theta},
        motor={"pole_pairs": 7, "stator_slots": 12},
    )


def test_candidate_orders_of_a_14_pole_12_slot_motor():
    c = candidate_orders(7, 12, 200)
    assert c["cogging"] == [84, 168]
    assert c["magnet_asymmetry"][:3] == [7, 14, 21]
    assert c["coil_mismatch"][:8] == [1, 2, 3, 4, 5, 6, 7, 12]


def test_motion_names_magnet_asymmetry_with_amplitudes(tmp_path):
    rec = _motion(tmp_path, {7: 0.05, 14: 0.02})
    d = diagnose(rec, max_order=100).doc
    validate_diagnosis(d)
    assert d["verdict"] == "missing_physics"
    assert d["effects"][0]["name"] == "magnet_asymmetry"
    ripple = d["effects"][0]["derived"]["speed_ripple_relative"]["value"]
    assert ripple["7"] == pytest.approx(0.05, rel=0.1)
    assert ripple["14"] == pytest.approx(0.02, rel=0.1)
    assert d["effects"][0]["heldout_rms_after"] < 0.8 * d["heldout_rms_before"]


def test_motion_clean_is_consistent(tmp_path):
    d = diagnose(_motion(tmp_path, {}), max_order=100).doc
    validate_diagnosis(d)
    assert d["verdict"] == "consistent"
    assert d["effects"] == [] and d["unexplained"] == []


def test_motion_out_of_catalog_order_is_unexplained(tmp_path):
    d = diagnose(_motion(tmp_path, {43: 0.2}), max_order=100).doc
    assert d["effects"] == []
    assert d["verdict"] == "unexplained"
    assert d["unexplained"][0]["where"]["orders"] == [43]


def _quad(tmp_path, h3=0.0, clip=None, n=3000, seed=1):
    rng = np.random.default_rng(seed)
    phi = rng.uniform(0, 2 * np.pi, n)

    def shape(x):
        return np.cos(x) + h3 * np.cos(3 * x)

    sa = 0.02 + 1.0 * shape(phi) + rng.normal(0, 1e-3, n)
    sb = -0.01 + 0.97 * shape(phi + 0.01 - np.pi / 2) + rng.normal(0, 1e-3, n)
    if clip is not None:
        sa, sb = np.clip(sa, -clip, clip), np.clip(sb, -clip, clip)
    return write_recording(tmp_path / "q.toml", "quadrature", {"sa": sa, "sb": sb})


def test_quadrature_ellipse_only_is_consistent_and_recovers_ellipse(tmp_path):
    d = diagnose_quadrature(_quad(tmp_path))
    assert d["verdict"] == "consistent"
    assert d["base"]["offset_a"] == pytest.approx(0.02, abs=2e-3)
    assert d["base"]["amplitude_ratio"] == pytest.approx(0.97, rel=2e-3)


def test_quadrature_names_signal_shape(tmp_path):
    d = diagnose_quadrature(_quad(tmp_path, h3=0.01))
    assert d["verdict"] == "missing_physics"
    e = d["effects"][0]
    assert e["name"] == "signal_shape"
    assert e["params"]["harmonics"]["3"]["relative_amplitude"] == pytest.approx(0.01, rel=0.1)
    assert e["heldout_rms_after"] < 0.8 * d["heldout_rms_before"]


def test_quadrature_clipping_is_unexplained_not_signal_shape(tmp_path):
    d = diagnose_quadrature(_quad(tmp_path, clip=0.93))
    assert d["unexplained"], d["report"]
    assert "clipping" in d["unexplained"][0]["note"]
    assert all(e["name"] != "signal_shape" for e in d["effects"])


def test_shipped_motor_record_names_pole_pair_orders():
    from encdesign import load_recording

    d = diagnose(load_recording(DATA / "odrive_nocomp.toml"), max_order=100).doc
    validate_diagnosis(d)
    assert d["effects"][0]["name"] == "magnet_asymmetry"
    assert d["effects"][0]["heldout_rms_after"] < 0.8 * d["heldout_rms_before"]


def test_cli_diagnose_refuses_malformed_motion(tmp_path, capsys):
    (tmp_path / "m.toml").write_text(
        'format = "encdesign-recording/1"\nkind = "motion"\ndata = "m.csv"\n'
        "[motor]\npole_pairs = 7.5\n"
    )
    (tmp_path / "m.csv").write_text("t,theta\n0,0\n1,1\n")
    assert main(["diagnose", str(tmp_path / "m.toml"), "--json", str(tmp_path / "o.json")]) == 2
    assert "pole_pairs" in capsys.readouterr().err
    assert not (tmp_path / "o.json").exists()


def test_shipped_interferometer_capture_beats_heydemann():
    """NMM X capture, every 4th sample: ellipse as Heydemann's, signal_shape named."""
    from encdesign import Recording, load_recording

    full = load_recording(DATA / "nmm_x.toml")
    rec = Recording(
        kind="quadrature",
        meta=full.meta,
        columns={k: v[::4] for k, v in full.columns.items()},
        path=full.path,
    )
    d = diagnose_quadrature(rec)
    assert d["base"]["offset_a"] == pytest.approx(d["heydemann"]["offset_a"], abs=0.5)
    assert [e["name"] for e in d["effects"]] == ["signal_shape"]
    assert d["effects"][0]["heldout_rms_after"] < 0.8 * d["heydemann"]["heldout_rms"]


def test_real_recordings_study_quick_json(tmp_path):
    import json

    out = tmp_path / "rr.json"
    assert (
        main(
            [
                "study",
                "run",
                "real-recordings",
                "--quick",
                "--out",
                str(tmp_path),
                "--json",
                str(out),
            ]
        )
        == 0
    )
    rows = json.loads(out.read_text())["recordings"]
    assert [r["name"] for r in rows] == ["nmm_x", "odrive_nocomp"]
    for r in rows:
        assert {"name", "kind", "verdict", "heldout_rms_before", "effects"} <= set(r)
        for e in r["effects"]:
            assert e["heldout_rms_after"] <= 0.8 * r["heldout_rms_before"]
    assert (tmp_path / "real-recordings-summary.png").exists()
