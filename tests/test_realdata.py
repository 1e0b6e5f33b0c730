"""The shipped real recordings load, and the converters refuse malformed sources."""

from pathlib import Path

import numpy as np
import pytest

from encdesign import EncdesignInputError, load_recording
from encdesign.cli import main
from encdesign.io._realdata import import_nmm, import_odrive, import_servo

DATA = Path(__file__).resolve().parent.parent / "data" / "real"


@pytest.mark.parametrize(
    ("name", "kind", "rows"),
    [
        ("nmm_x", "quadrature", 16511),
        ("nmm_y", "quadrature", 16511),
        ("odrive_nocomp", "motion", 4306),
        ("odrive_comp", "motion", 4377),
        ("odrive_nocomp_1", "motion", 4267),
        ("odrive_comp_1", "motion", 4367),
    ],
)
def test_shipped_recordings_load_with_provenance(name, kind, rows):
    rec = load_recording(DATA / f"{name}.toml")
    assert rec.kind == kind
    assert rec.n_rows == rows
    assert "MIT License" in rec.meta["provenance"]["license"]


def test_nmm_signals_are_on_the_lissajous_circle():
    rec = load_recording(DATA / "nmm_x.toml")
    r = np.hypot(rec.columns["sa"], rec.columns["sb"])
    assert 490 < r.min() < r.max() < 510  # ADC counts, as the source's radius column


def test_odrive_is_one_turn_in_ten_seconds():
    rec = load_recording(DATA / "odrive_nocomp.toml")
    turns = np.ptp(rec.columns["counts"]) / rec.encoder["counts_per_rev"]
    assert 0.95 < turns < 1.01
    assert 9.9 < np.ptp(rec.columns["t"]) < 10.1
    assert rec.meta["motor"] == {"pole_pairs": 7, "stator_slots": 12}


def test_import_round_trip(tmp_path):
    src = tmp_path / "nmm_Q_raw.csv"
    phase = np.linspace(0, 359, 50)
    rows = "\n".join(f"{p}, {500 + np.sin(np.deg2rad(p))}, 0.0" for p in phase)
    src.write_text("Phase (deg), Radius, Roundness deviation\n" + rows + "\n")
    rec = import_nmm(src, tmp_path / "q.toml")
    back = load_recording(tmp_path / "q.toml")
    np.testing.assert_allclose(back.columns["sa"], rec.columns["sa"], rtol=0, atol=1e-12)
    assert "Q interferometer" in back.meta["description"]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("a,b,c\n1,2,3\n", "header"),
        ("Phase (deg), Radius, Roundness deviation\n1, x, 3\n2,3,4\n3,4,5\n", "non-numeric"),
        ("Phase (deg), Radius, Roundness deviation\n1, nan, 3\n2,3,4\n3,4,5\n", "non-finite"),
        ("Phase (deg), Radius, Roundness deviation\n1, -1, 3\n2,3,4\n3,4,5\n", "radius"),
    ],
)
def test_nmm_refusals(tmp_path, content, message):
    src = tmp_path / "bad.csv"
    src.write_text(content)
    with pytest.raises(EncdesignInputError, match=message):
        import_nmm(src, tmp_path / "out.toml")
    assert not (tmp_path / "out.toml").exists()


def test_odrive_refusals(tmp_path):
    np.save(tmp_path / "bad.npy", np.zeros((2, 10)))
    with pytest.raises(EncdesignInputError, match=r"shape \[3, N\]"):
        import_odrive(tmp_path / "bad.npy", tmp_path / "out.toml")
    a = np.vstack([np.arange(10.0), np.arange(10.0), np.zeros(10)])
    a[0, 5] = 1.0  # time goes backwards
    np.save(tmp_path / "back.npy", a)
    with pytest.raises(EncdesignInputError, match="time goes backwards"):
        import_odrive(tmp_path / "back.npy", tmp_path / "out.toml")


def test_cli_import_bad_file_exits_2(tmp_path, capsys):
    assert main(["import", "odrive", str(tmp_path / "missing.npy"), "--out", "x.toml"]) == 2
    assert "not found" in capsys.readouterr().err


def test_shipped_servo_capture_loads_with_attribution():
    rec = load_recording(DATA / "servo_optical.toml")
    assert rec.kind == "quadrature" and rec.n_rows == 26168
    prov = rec.meta["provenance"]
    assert "CC BY 3.0 US" in prov["license"] and "Bäckström" in prov["license"]
    assert "ServoProject" in prov["source"]
    # raw ADC counts of a 14-bit range, no plateau at the extremes, t in s at 4.2 ms
    for c in ("sa", "sb"):
        x = rec.columns[c]
        assert np.all(x == np.round(x)) and 0 < x.min() < x.max() < 16384
        assert np.sum(x == x.max()) < 5 and np.sum(x == x.min()) < 5
    assert np.median(np.diff(rec.columns["t"])) == pytest.approx(0.0042, abs=1e-6)


def _servo_src(tmp_path, lines):
    src = tmp_path / "servo.txt"
    src.write_text("\n".join(lines) + "\n")
    return src


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ("0.1 5702 14721 30", "number of columns"),
        ("0.1 5702.5 14721 30 5", "ADC count"),
        ("0.1 5702 70000 30 5", "ADC count"),
        ("0.0 5702 14721 30 5", "not increasing"),
        ("0.1 x 14721 30 5", "non-numeric"),
    ],
)
def test_servo_refusals(tmp_path, bad, message):
    good = [f"{0.01 * (i + 1):.4f} {5000 + i} {9000 + i} {i} 3" for i in range(40)]
    lines = good[:10] + [bad] + good[11:]
    if "not increasing" in message:
        lines = good[:10] + [f"{0.01 * 9:.4f} 5702 14721 30 5"] + good[11:]
    with pytest.raises(EncdesignInputError, match=message):
        import_servo(_servo_src(tmp_path, lines), tmp_path / "out.toml")
    assert not (tmp_path / "out.toml").exists()


def test_servo_import_round_trip(tmp_path):
    lines = [
        f"{0.0042 * (i + 1):.4f} {5000 + 7 * i} {9000 + 3 * i} {i % 2048} 3" for i in range(40)
    ]
    rec = import_servo(_servo_src(tmp_path, lines), tmp_path / "s.toml")
    back = load_recording(tmp_path / "s.toml")
    assert sorted(back.columns) == ["sa", "sb", "t"]
    np.testing.assert_array_equal(back.columns["sa"], rec.columns["sa"])
    assert back.columns["sb"][-1] == 9000 + 3 * 39
