"""Every command under bad input and hostile paths (issue 12): each case class of the issue
re-run, and every input hashed before and after every command.

A case passes when the command exits as the contract says (``0``, ``1`` or ``2``), prints
exactly one line on stderr when it refuses, leaves its inputs byte-identical and, when it
refuses, leaves no file or folder behind (no output, no temporary file, no case file).
"""

from __future__ import annotations

import gzip
import hashlib
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from encdesign.cli._main import main

REALDATA = Path("/work/shared/realdata")

DESIGN = """\
format = "encdesign-design/1"
description = "small 3+1 test bench"
[disk]
optical_radius_m = 0.0254
eccentricity_m = [5e-6, 0.0]
[heads]
angles_deg = [0.0, 120.0, 240.0, 22.0]
reference_head = 3
noise_rad = 1e-7
[[bench.runs]]
speed_rev_per_s = 1.0
end_time_s = 1.0
sample_rate_hz = 256.0
[[bench.runs]]
speed_rev_per_s = 2.0
end_time_s = 1.0
sample_rate_hz = 256.0
"""

PROBLEM = """\
[problem]
name = "tiny"
objective = "cotangent_sensitivity"
[model]
n_heads = 3
max_order = 4
n_builds = 0
[variables.reference_angle]
units = "deg"
start = 20.0
lower = 14.0
upper = 28.0
[driver]
kind = "grid"
points_per_dim = 3
[sweep]
kind = "grid"
points_per_dim = 3
"""


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _snapshot(root: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file under ``root`` (folders as ``"<dir>"``)."""
    out = {}
    for p in sorted(root.rglob("*")):
        out[str(p.relative_to(root))] = "<dir>" if p.is_dir() else _digest(p)
    return out


@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Path:
    """A folder with a design, its simulated recording, a problem, an sds recording, an
    NmmQuad CSV and an ODrive .npy (all small)."""
    d = tmp_path_factory.mktemp("bench")
    (d / "design.toml").write_text(DESIGN)
    (d / "p.toml").write_text(PROBLEM)
    assert main(["simulate", str(d / "design.toml"), "--out", str(d / "rec.toml")]) == 0
    args = ["sds", "simulate", "--out", str(d / "sds.toml"), "--marks", "60", "--revs", "1"]
    assert main([*args, "--phi-deg", "0", "90"]) == 0
    phase = np.linspace(0.0, 359.0, 360)
    rows = "\n".join(f"{p!r},{1000.0 + np.sin(p):.6f},0.1" for p in phase.tolist())
    (d / "nmm_X_raw.csv").write_text("Phase (deg),Radius,Roundness deviation\n" + rows + "\n")
    t = np.linspace(0.0, 10.0, 500)
    np.save(d / "odrive.npy", np.stack([t, 819.2 * t, 0.1 * np.sin(t)]))
    return d


@pytest.fixture
def work(bench, tmp_path) -> Path:
    """A fresh copy of the bench folder for one case."""
    w = tmp_path / "w"
    shutil.copytree(bench, w)
    return w


def _run(argv, capsys) -> tuple[int, str]:
    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr().err


def _refused(work: Path, argv, capsys, *needles: str) -> str:
    """Run; assert exit 2, one line on stderr (containing ``needles``), nothing changed."""
    before = _snapshot(work)
    rc, err = _run(argv, capsys)
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err and "np.float64(" not in err
    for n in needles:
        assert n in err, err
    assert _snapshot(work) == before
    return lines[0]


# ----------------------------------------------------------------------------- item 1


@pytest.mark.parametrize(
    "argv",
    [
        ["diagnose", "{w}/rec.toml", "--json", "{w}/rec.toml"],
        ["diagnose", "{w}/rec.toml", "--json", "{w}/rec.csv"],
        ["diagnose", "{w}/rec.toml", "--json", "{w}/x.json", "--report", "{w}/x.json"],
        ["simulate", "{w}/design.toml", "--out", "{w}/design.toml"],
        ["simulate", "{w}/design.toml", "--like", "{w}/rec.toml", "--out", "{w}/rec.toml"],
        ["simulate", "{w}/design.toml", "--out", "{w}/sim.csv"],
        ["optimize", "{w}/p.toml", "--json", "{w}/p.toml"],
        ["optimize", "{w}/p.toml", "--json", "{w}/o.json", "--cases", "{w}/p.toml"],
        ["sweep", "{w}/p.toml", "--cases", "{w}/p.toml"],
        ["check-gradients", "{w}/p.toml", "--json", "{w}/p.toml"],
        ["sds", "measure", "{w}/sds.toml", "--json", "{w}/sds.csv"],
        ["import", "nmm", "{w}/nmm_X_raw.csv", "--out", "{w}/nmm_X_raw.toml"],
        ["import", "odrive", "{w}/odrive.npy", "--out", "{w}/odrive.npy"],
        ["conceal", "{w}/c.toml", "--truth", "{w}/c.toml"],
        ["conceal", "{w}/c.toml", "--truth", "{w}/c.csv"],
        ["conceal", "{w}/rec.toml", "--truth", "{w}/t.json"],  # would destroy rec.toml? no:
    ][:-1],
)
def test_never_writes_over_an_input_or_another_output(work, capsys, argv):
    _refused(work, [a.format(w=work) for a in argv], capsys)


def test_links_resolve_to_the_input(work, capsys):
    os.symlink(work / "rec.toml", work / "link.json")
    _refused(work, ["diagnose", work / "rec.toml", "--json", work / "link.json"], capsys, "link")
    os.link(work / "p.toml", work / "hard.json")
    _refused(work, ["optimize", work / "p.toml", "--json", work / "hard.json"], capsys)
    (work / "sub").mkdir()
    os.symlink(work, work / "sub" / "up")
    _refused(work, ["diagnose", work / "rec.toml", "--json", work / "sub/up/rec.csv"], capsys)


def test_derived_table_name_is_checked(work, capsys):
    # --out nmm_X_raw.toml would write its table to nmm_X_raw.csv, the source
    line = _refused(
        work, ["import", "nmm", work / "nmm_X_raw.csv", "--out", work / "nmm_X_raw.toml"], capsys
    )
    assert "nmm_X_raw.csv" in line
    # the gzip table name is derived too: X.toml --gzip writes X.csv.gz, the --like table
    (work / "X.csv.gz").write_bytes(gzip.compress((work / "rec.csv").read_bytes()))
    toml = (work / "rec.toml").read_text().replace('data = "rec.csv"', 'data = "X.csv.gz"')
    (work / "a.toml").write_text(toml)
    argv = ["simulate", work / "design.toml", "--like", work / "a.toml", "--out"]
    line = _refused(work, [*argv, work / "X.toml", "--gzip"], capsys)
    assert "X.csv.gz" in line


# ----------------------------------------------------------------------------- item 2


def test_output_path_problems_refused_before_any_work(work, capsys):
    (work / "DIR.toml").mkdir()
    _refused(work, ["simulate", work / "design.toml", "--out", work / "DIR.toml"], capsys, "folder")
    _refused(work, ["diagnose", work / "rec.toml", "--json", work / "p.toml/x.json"], capsys)
    _refused(work, ["diagnose", work / "rec.toml", "--json", work / "DIR.toml"], capsys, "folder")
    _refused(work, ["optimize", work / "p.toml", "--json", "/proc/version/x.json"], capsys)
    ro = work / "ro.json"
    ro.write_text("{}")
    ro.chmod(0o444)
    _refused(work, ["optimize", work / "p.toml", "--json", ro], capsys, "read-only")
    _refused(work, ["diagnose", work / "rec.toml", "--json", "/proc/encdesign.json"], capsys)


def test_refusal_leaves_nothing_behind(work, capsys):
    # an invalid [model] value: no case file, no JSON, no folder
    bad = work / "bad.toml"
    bad.write_text(PROBLEM.replace("max_order = 4", "max_order = -3"))
    _refused(
        work,
        ["optimize", bad, "--cases", work / "new/cases.csv", "--json", work / "new/o.json"],
        capsys,
        "max_order",
    )
    assert not (work / "new").exists()
    # import realdata refusing on its third source: nothing written, no folder created
    src = work / "real"
    src.mkdir()
    shutil.copy(work / "nmm_X_raw.csv", src / "nmm_X_raw.csv")
    shutil.copy(work / "nmm_X_raw.csv", src / "nmm_Y_raw.csv")
    shutil.copy(work / "odrive.npy", src / "odrive_slow2_nocomp_0.npy")
    (src / "odrive_slow2_comp_0.npy").write_bytes(b"\x93NUMPY garbage")
    _refused(work, ["import", "realdata", src, "--out", work / "out"], capsys)
    assert not (work / "out").exists()


# ----------------------------------------------------------------------------- item 3


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ("max_order = 4", "max_order = -3", "max_order"),
        ("max_order = 4", "max_order = 4\nn_angles = 0", "n_angles"),
        ("n_heads = 3", "n_heads = 0", "n_heads"),
        ("n_builds = 0", "n_builds = -5", "n_builds"),
        ("n_builds = 0", "n_builds = 0\nsigma_placement = -1e-4", "sigma_placement"),
        ("n_builds = 0", "n_builds = 0\nsigma_placement = nan", "sigma_placement"),
        ("[model]\n", "model = 5\n[x]\n", "model"),
        ('[driver]\nkind = "grid"\npoints_per_dim = 3\n', 'driver = "bfgs"\n', "driver"),
        ("points_per_dim = 3\n", "points_per_dim = 100000000\n", "points_per_dim"),
        ("seed" if False else "[problem]\n", "[problem]\nseed = 18446744073709551616\n", "seed"),
    ],
)
def test_problem_values_validated_where_parsed(work, capsys, old, new, key):
    bad = work / "bad.toml"
    bad.write_text(PROBLEM.replace(old, new, 1))
    line = _refused(work, ["optimize", bad], capsys, key)
    assert "bad.toml" in line


TOL = (Path(__file__).resolve().parents[1] / "examples" / "tolerance_cost_3p1.toml").read_text()


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ('spec_units = "urad"', 'spec_units = "m"', "spec_units"),
        ("n_angles = 24", "n_angles = 24\npercentile = 150.0", "percentile"),
        ("radius_m = 0.0254", "radius_m = -0.0254", "radius_m"),
        ("radius_m = 0.0254", "radius_m = 0.0", "radius_m"),
        ("n_angles = 24", "n_angles = 0", "n_angles"),
        ("sigma_tilt = 1e-3", "sigma_tilt = -1e-3", "sigma_tilt"),
    ],
)
def test_tolerance_problem_values(work, capsys, old, new, key):
    bad = work / "tol.toml"
    assert old in TOL
    bad.write_text(TOL.replace(old, new, 1))
    _refused(work, ["optimize", bad], capsys, key, "tol.toml")


def test_sds_model_values(work, capsys):
    bad = work / "sds_p.toml"
    bad.write_text(
        '[problem]\nobjective = "sds_residual"\n[model]\nn_phi = 0\n'
        "[variables.pole_pairs]\nvalues = [4, 6]\n"
    )
    _refused(work, ["optimize", bad], capsys, "n_phi")


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ("speed_rev_per_s = 1.0", "speed_rev_per_s = 1e300", "speed_rev_per_s"),
        ("optical_radius_m = 0.0254", "optical_radius_m = -1.0", "optical_radius_m"),
        ("optical_radius_m = 0.0254", "optical_radius_m = 1e300", "optical_radius_m"),
        ("noise_rad = 1e-7", "noise_rad = -1e-7", "noise_rad"),
        ("noise_rad = 1e-7", "noise_rad = nan", "noise_rad"),
        ("end_time_s = 1.0", "end_time_s = 1e300", "end_time_s"),
    ],
)
def test_design_values_validated_where_parsed(work, capsys, old, new, key):
    bad = work / "d.toml"
    bad.write_text(DESIGN.replace(old, new, 1))
    _refused(work, ["simulate", bad, "--out", work / "o.toml"], capsys, key, "d.toml")


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "{w}/design.toml", "--out", "{w}/o.toml", "--seed", str(2**64)],
        ["simulate", "{w}/design.toml", "--out", "{w}/o.toml", "--seed", "-1"],
        ["conceal", "{w}/c.toml", "--samples-per-run", "0"],
        ["conceal", "{w}/c.toml", "--samples-per-run", "-5"],
        ["conceal", "{w}/c.toml", "--amplitude", "1e300"],
        ["conceal", "{w}/c.toml", "--amplitude", "nan"],
        ["check-gradients", "{w}/p.toml", "--rel-step", "0"],
        ["check-gradients", "{w}/p.toml", "--rtol", "nan"],
        ["diagnose", "{w}/rec.toml", "--json", "{w}/o.json", "--max-order", "0"],
        ["sds", "simulate", "--out", "{w}/s.toml", "--marks", "0"],
        ["sds", "measure", "{w}/sds.toml", "--revs-per-reading", "0"],
        ["sds", "simulate", "--out", "{w}/s.toml", "--marks", "10000000", "--revs", "1000"],
    ],
)
def test_argument_values_refused(work, capsys, argv):
    _refused(work, [a.format(w=work) for a in argv], capsys)


def test_check_gradients_without_continuous_variables(work, capsys):
    p = work / "disc.toml"
    p.write_text(
        '[problem]\nobjective = "cotangent_sensitivity"\n[model]\nmax_order = 4\n'
        "[variables.n_heads]\nvalues = [3, 4]\n"
    )
    _refused(work, ["check-gradients", p], capsys, "no continuous variables")


def test_max_order_beyond_the_samples(work, capsys):
    line = _refused(
        work,
        ["diagnose", work / "rec.toml", "--json", work / "o.json", "--max-order", "5000"],
        capsys,
    )
    # the engine states the limit the record supports (span, sampling, parameter fraction)
    assert "--max-order" in line and "max order <= " in line
    limit = int(line.rsplit("<=", 1)[1].strip(" )"))
    assert 1 <= limit < 5000


# ----------------------------------------------------------------------------- items 3, 5


def _csv(work: Path) -> str:
    return (work / "rec.csv").read_text()


def _set_csv(work: Path, text: str, name: str = "rec.csv") -> Path:
    (work / name).write_bytes(text.encode() if isinstance(text, str) else text)
    return work / "rec.toml"


def _diag(work):
    return ["diagnose", work / "rec.toml", "--json", work / "o.json", "--quiet"]


def test_absurd_cells_refused(work, capsys):
    lines = _csv(work).splitlines()
    head, row = lines[0].split(","), lines[5].split(",")
    row[head.index("h1")] = "1e300"
    lines[5] = ",".join(row)
    _set_csv(work, "\n".join(lines) + "\n")
    _refused(work, _diag(work), capsys, "line 6", "h1")


def test_absurd_times_refused(work, capsys):
    lines = _csv(work).splitlines()
    head = lines[0].split(",")
    it = head.index("t")
    out = [lines[0]]
    for s in lines[1:]:
        f = s.split(",")
        f[it] = repr(float(f[it]) * 1e300 + 1e300)
        out.append(",".join(f))
    _set_csv(work, "\n".join(out) + "\n")
    _refused(work, _diag(work), capsys, "column 't'")


def test_run_id_beyond_int64_refused(work, capsys):
    lines = _csv(work).splitlines()
    head = lines[0].split(",")
    for value in ("1e30", "99999999999999999999"):
        f = lines[3].split(",")
        f[head.index("run")] = value
        _set_csv(work, "\n".join([*lines[:3], ",".join(f), *lines[4:]]) + "\n")
        _refused(work, _diag(work), capsys, "line 4", "run")


def test_corrupt_and_truncated_gzip_refused(work, capsys):
    data = gzip.compress(_csv(work).encode())
    toml = (work / "rec.toml").read_text().replace('data = "rec.csv"', 'data = "rec.csv.gz"')
    (work / "rec.toml").write_text(toml)
    for blob in (data[: len(data) // 2], data[:20] + b"\x00" * 50 + data[70:], b"plain text"):
        (work / "rec.csv.gz").write_bytes(blob)
        _refused(work, _diag(work), capsys, "rec.csv.gz")


def test_binary_and_npz_given_to_import(work, capsys):
    (work / "bin.csv").write_bytes(bytes(range(256)) * 4)
    _refused(work, ["import", "nmm", work / "bin.csv", "--out", work / "o.toml"], capsys, "bin.csv")
    np.savez(work / "arr.npz", a=np.zeros((3, 10)))
    shutil.move(work / "arr.npz", work / "arr.npy")
    _refused(work, ["import", "odrive", work / "arr.npy", "--out", work / "o.toml"], capsys, ".npz")
    (work / "junk.npy").write_bytes(b"not numpy at all")
    _refused(work, ["import", "odrive", work / "junk.npy", "--out", work / "o.toml"], capsys)


def test_bom_crlf_blank_lines_trailing_commas_read(work, capsys):
    text = _csv(work)
    lines = text.splitlines()
    weird = "\ufeff" + "\r\n".join([lines[0] + ",", "", *(s + "," for s in lines[1:])]) + "\r\n"
    _set_csv(work, weird)
    rc, err = _run(
        ["simulate", work / "design.toml", "--like", work / "rec.toml", "--out", work / "sim.toml"],
        capsys,
    )
    assert rc == 0, err
    # line numbers stay right after a blank line
    lines2 = [lines[0], "", "", *lines[1:]]
    f = lines2[4].split(",")
    f[1] = "oops"
    lines2[4] = ",".join(f)
    _set_csv(work, "\n".join(lines2) + "\n")
    _refused(work, _diag(work), capsys, "line 5", "oops")


def test_weak_messages_fixed(work, capsys):
    toml = (work / "rec.toml").read_text()
    (work / "rec.toml").write_text(toml.replace("reference_head = 3", "reference_head = 7"))
    line = _refused(work, _diag(work), capsys, "reference_head")
    assert "rec.toml" in line and "rec.csv" not in line
    (work / "rec.toml").write_text(toml)
    lines = _csv(work).splitlines()
    _set_csv(work, "\n".join([lines[0] + ",", *[s + ",1" for s in lines[1:]]]) + "\n")
    _refused(work, _diag(work), capsys, "field")
    _set_csv(work, "\n".join([lines[0].replace("h1", ""), *lines[1:]]) + "\n")
    _refused(work, _diag(work), capsys, "empty name")


def test_interleaved_runs_name_a_line(work, capsys):
    lines = _csv(work).splitlines()
    body = lines[1:]
    head = lines[0].split(",")
    ir = head.index("run")
    r0 = [s for s in body if s.split(",")[ir] == "0"]
    r1 = [s for s in body if s.split(",")[ir] == "1"]
    mixed = r0[:100] + r1[:100] + r0[100:] + r1[100:]
    _set_csv(work, "\n".join([lines[0], *mixed]) + "\n")
    _refused(work, _diag(work), capsys, "line 202", "interleaved")


# ----------------------------------------------------------------------------- item 6


def test_internal_error_is_one_line(monkeypatch, capsys, work):
    import encdesign.cli._simulate as sim

    def boom(args):
        raise RuntimeError("boom\nsecond line")

    monkeypatch.setattr(sim, "run", boom)
    rc, err = _run(["simulate", work / "design.toml", "--out", work / "o.toml"], capsys)
    assert rc == 3
    assert len(err.strip().splitlines()) == 1 and "--debug" in err and "internal error" in err
    with pytest.raises(RuntimeError):
        main(["--debug", "simulate", str(work / "design.toml"), "--out", str(work / "o.toml")])


def test_usage_error_is_one_line(capsys):
    rc, err = _run(["simulate"], capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1


# ----------------------------------------------------------------------------- hashing


COMMANDS = [
    ["simulate", "{w}/design.toml", "--out", "{w}/o/sim.toml"],
    ["simulate", "{w}/design.toml", "--like", "{w}/rec.toml", "--out", "{w}/o/like.toml", "--gzip"],
    ["conceal", "{w}/o/c.toml", "--samples-per-run", "300", "--truth", "{w}/o/truth.json"],
    ["import", "nmm", "{w}/nmm_X_raw.csv", "--out", "{w}/o/nmm.toml"],
    ["import", "odrive", "{w}/odrive.npy", "--out", "{w}/o/od.toml"],
    ["sds", "measure", "{w}/sds.toml", "--json", "{w}/o/m.json"],
    ["sds", "simulate", "--out", "{w}/o/s.toml", "--marks", "60", "--revs", "1", "--phi-deg", "0"],
    ["diagnose", "{w}/rec.toml", "--json", "{w}/o/d.json", "--report", "{w}/o/d.txt", "--quiet"],
    ["import", "realdata", str(REALDATA), "--out", "{w}/o/real"],
    ["optimize", "{w}/p.toml", "--json", "{w}/o/o.json", "--cases", "{w}/o/c.jsonl", "--quiet"],
    ["sweep", "{w}/p.toml", "--cases", "{w}/o/c.csv", "--quiet"],
    ["check-gradients", "{w}/p.toml", "--json", "{w}/o/g.json"],
]


@pytest.mark.parametrize("argv", COMMANDS, ids=lambda a: " ".join(a[:2]))
def test_inputs_unchanged_by_every_command(work, capsys, argv):
    if "realdata" in argv and not REALDATA.is_dir():
        pytest.skip("shared real data not present")
    extra = sorted(REALDATA.glob("*")) if "realdata" in argv else []
    before = _snapshot(work) | {str(p): _digest(p) for p in extra}
    rc, err = _run([a.format(w=work) for a in argv], capsys)
    assert rc in (0, 1), err
    after = _snapshot(work) | {str(p): _digest(p) for p in extra}
    for name, digest in before.items():
        assert after.get(name) == digest, name
    assert not [n for n in after if ".tmp" in n], after
