"""Design files, `encdesign simulate`, and multihead recordings: round trip and refusals."""

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from encdesign import (
    EncdesignInputError,
    head_readings,
    load_design,
    load_recording,
    simulate_recording,
    write_recording,
)
from encdesign.cli import main
from encdesign.design import parse_design

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "design-3plus1.toml"

SMALL = {
    "format": "encdesign-design/1",
    "description": "small 3+1 test design",
    "disk": {
        "optical_radius_m": 0.0254,
        "eccentricity_m": [5e-6, 0.0],
        "tilt_rad": [6e-3, 0.0],
        "grating_sin_rad": [0.0, 0.0, 5e-6],
    },
    "heads": {
        "angles_deg": [0.0, 120.0, 240.0, 22.0],
        "reference_head": 3,
        "placement_error_rad": [0.0, 1e-5, -1e-5, 0.0],
        "noise_rad": 1e-7,
    },
    "bench": {
        "runs": [
            {"speed_rev_per_s": 1.0, "end_time_s": 1.0, "sample_rate_hz": 128.0},
            {"speed_rev_per_s": 2.0, "end_time_s": 0.5, "sample_rate_hz": 256.0},
        ]
    },
}


def _write_design(path: Path, raw: dict) -> Path:
    path.write_bytes(tomli_w.dumps(raw).encode())
    return path


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _variant(**changes) -> dict:
    import copy

    raw = copy.deepcopy(SMALL)
    for dotted, value in changes.items():
        *parents, key = dotted.split(".")
        tab = raw
        for p in parents:
            tab = tab[p]
        tab[key] = value
    return raw


def test_example_design_loads():
    d = load_design(EXAMPLE)
    assert d.n_heads == 4 and d.reference_head == 3 and d.grating_lines == 10000
    assert d.symmetric_heads == (0, 1, 2)
    np.testing.assert_allclose(d.model.disk.eccentricity_m, [5e-6, 0.0])
    np.testing.assert_allclose(d.model.heads.angles_rad, np.deg2rad([0, 120, 240, 22]))
    assert len(d.runs) == 2 and d.runs[0].n_samples == 2048


def test_simulate_round_trip(tmp_path):
    design = parse_design(SMALL, "small")
    out = tmp_path / "rec.toml"
    rec = simulate_recording(design, out, seed=4)
    back = load_recording(out)
    assert back.kind == "multihead" and back.n_rows == 256
    assert back.encoder["head_angles_deg"] == [0.0, 120.0, 240.0, 22.0]
    assert back.encoder["reference_head"] == 3
    for name, col in rec.columns.items():
        np.testing.assert_array_equal(back.columns[name], col)  # repr floats: exact
    assert set(np.unique(back.runs)) == {0, 1}
    # readings are the model's plus noise of the design's std
    clean = np.asarray(head_readings(design.model, back.columns["theta_ref"], back.columns["t"]))
    noise = back.heads() - clean
    assert 0.7e-7 < noise.std() < 1.3e-7
    # same seed -> same data; another seed -> other noise
    again = simulate_recording(design, tmp_path / "again.toml", seed=4)
    np.testing.assert_array_equal(again.heads(), rec.heads())
    other = simulate_recording(design, tmp_path / "other.toml", seed=5)
    assert np.max(np.abs(other.heads() - rec.heads())) > 1e-8


def test_cli_simulate_and_like(tmp_path, capsys):
    design = _write_design(tmp_path / "d.toml", SMALL)
    before = _sha(design)
    out = tmp_path / "out" / "rec.toml"
    assert main(["simulate", str(design), "--out", str(out), "--seed", "1"]) == 0
    assert "256 samples" in capsys.readouterr().out
    assert _sha(design) == before  # input never modified
    like = tmp_path / "like.toml"
    assert main(["simulate", str(design), "--out", str(like), "--like", str(out)]) == 0
    a, b = load_recording(out), load_recording(like)
    np.testing.assert_array_equal(a.columns["t"], b.columns["t"])
    np.testing.assert_array_equal(a.columns["theta_ref"], b.columns["theta_ref"])


def test_cli_simulates_the_example_design(tmp_path):
    """The shipped example design through ``encdesign simulate``, in this process (CI time:
    no interpreter to start; ``tests/test_cli.py::test_console_script_runs`` runs the
    console script itself)."""
    out = tmp_path / "r.toml"
    assert main(["simulate", str(EXAMPLE), "--out", str(out)]) == 0
    assert load_recording(out).n_rows == 3072


BAD_DESIGNS = {
    "wrong head count": (
        {"heads.placement_error_rad": [0.0, 1e-5, 0.0]},
        "placement_error_rad: 3 values",
    ),
    "reference head out of range": ({"heads.reference_head": 4}, "reference_head"),
    "non-finite value": ({"disk.tilt_rad": [float("nan"), 0.0]}, "tilt_rad[0]"),
    "infinite noise": ({"heads.noise_rad": float("inf")}, "noise_rad"),
    "unknown key in table": ({"disk.eccentricty_m": [1e-6, 0.0]}, "eccentricty_m"),
    "unknown top-level key": ({"bearing": {}}, "bearing"),
    "time going backwards": (
        {"bench.runs": [{"start_time_s": 2.0, "end_time_s": 1.0}]},
        "time goes backwards",
    ),
    "negative radius": ({"disk.optical_radius_m": -0.01}, "optical_radius_m"),
}


@pytest.mark.parametrize("case", sorted(BAD_DESIGNS))
def test_bad_design_refused_with_exit_2(tmp_path, capsys, case):
    changes, needle = BAD_DESIGNS[case]
    path = _write_design(tmp_path / "bad.toml", _variant(**changes))
    before = _sha(path)
    out = tmp_path / "never.toml"
    assert main(["simulate", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1  # one clear line
    assert str(path) in err and needle in err, err
    assert not out.exists() and not (tmp_path / "never.csv").exists()
    assert _sha(path) == before
    with pytest.raises(EncdesignInputError, match="bad.toml"):
        load_design(path)


def _good_recording(tmp_path: Path) -> Path:
    design = parse_design(SMALL, "small")
    path = tmp_path / "good.toml"
    simulate_recording(design, path, seed=0)
    return path


def _edit_csv(path: Path, edit) -> None:
    lines = path.read_text().splitlines()
    path.write_text("\n".join(edit(lines)) + "\n")


def _drop_column(lines, name):
    header = lines[0].split(",")
    i = header.index(name)
    return [",".join(c for k, c in enumerate(line.split(",")) if k != i) for line in lines]


def _set_cell(lines, row, name, value):
    header = lines[0].split(",")
    cells = lines[row].split(",")
    cells[header.index(name)] = value
    lines[row] = ",".join(cells)
    return lines


def _add_column(lines, name):
    return [lines[0] + f",{name}"] + [line + ",0.0" for line in lines[1:]]


BAD_RECORDINGS = {
    "missing head column": (lambda p: _edit_csv(p, lambda ls: _drop_column(ls, "h3")), "h3"),
    "extra head column": (lambda p: _edit_csv(p, lambda ls: _add_column(ls, "h4")), "h4"),
    "non-finite value": (
        lambda p: _edit_csv(p, lambda ls: _set_cell(ls, 5, "h1", "nan")),
        "line 6, column 'h1'",  # lines[5] is line 6 of the file
    ),
    "time going backwards": (
        lambda p: _edit_csv(p, lambda ls: _set_cell(ls, 10, "t", "0.0")),
        "time goes backwards",
    ),
    "unknown key": (
        lambda p: p.with_suffix(".toml").write_text(
            p.with_suffix(".toml").read_text().replace("[encoder]", "[encoder]\nspeed = 1.0")
        ),
        "speed",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_RECORDINGS))
def test_bad_recording_refused(tmp_path, capsys, case):
    good = _good_recording(tmp_path)
    breaker, needle = BAD_RECORDINGS[case]
    breaker(good.with_suffix(".csv"))
    before = (_sha(good), _sha(good.with_suffix(".csv")))
    with pytest.raises(EncdesignInputError, match="good") as exc:
        load_recording(good)
    assert needle in str(exc.value)
    # the CLI refuses it too (simulate --like reads the recording): exit 2, one line
    design = _write_design(tmp_path / "d.toml", SMALL)
    out = tmp_path / "never.toml"
    assert main(["simulate", str(design), "--out", str(out), "--like", str(good)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err
    assert not out.exists()
    assert (_sha(good), _sha(good.with_suffix(".csv"))) == before


def test_recording_head_count_must_match_design(tmp_path, capsys):
    good = _good_recording(tmp_path)
    raw = _variant(**{"heads.angles_deg": [0.0, 120.0, 240.0], "heads.reference_head": 2})
    raw["heads"]["placement_error_rad"] = [0.0, 0.0, 0.0]
    design = _write_design(tmp_path / "three.toml", raw)
    out = tmp_path / "never.toml"
    assert main(["simulate", str(design), "--out", str(out), "--like", str(good)]) == 2
    assert "4 heads but the design has 3" in capsys.readouterr().err


def test_write_recording_refuses_wrong_head_count(tmp_path):
    cols = {"t": np.arange(4.0), "h0": np.zeros(4), "h1": np.zeros(4)}
    with pytest.raises(EncdesignInputError, match="h2"):
        write_recording(
            tmp_path / "x.toml",
            "multihead",
            cols,
            encoder={"optical_radius_m": 0.02, "head_angles_deg": [0.0, 120.0, 240.0]},
        )
    assert not (tmp_path / "x.toml").exists()


def test_example_copy_is_untouched_by_simulation(tmp_path):
    copy = tmp_path / "design.toml"
    shutil.copy(EXAMPLE, copy)
    before = _sha(copy)
    simulate_recording(load_design(copy), tmp_path / "r.toml", seed=0)
    assert _sha(copy) == before
