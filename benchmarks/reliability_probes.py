"""Probes of issue 24 (reliability, second round): each probe class, counted.

Run against a tree with ``PYTHONPATH=<tree> python benchmarks/reliability_probes.py``
(``--tree`` only labels the output). Every probe runs the CLI in a fresh process inside a
scratch folder and is judged by the issue's acceptance: input files intact, nothing left
behind on refusal, no exit 0 without outputs, exit 2 with a message naming the flag/key.
Prints one line per probe and the count of mishandled probes per class.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent

SWEEP = """
[problem]
name = {name}
objective = "residual"
seed = 1

[model]
radius_m = 0.0254
n_heads = 3
max_order = 4
grating_orders = 4
n_angles = 32
n_builds = 40
sigma_placement = 2e-4

[variables.reference_angle]
units = "deg"
start = 20.0
lower = 14.0
upper = {upper}

[sweep]
kind = "grid"
points_per_dim = 3
"""

USER_MOD = "import sys\n{at_import}\n" + (
    "import encdesign\n"
    "@encdesign.objective_function(variables={{'a': encdesign.variable('1')}}, outputs=('f',))\n"
    "def fn(x, discrete, model, key):\n    {in_fn}\n    return {{'f': x['a'] ** 2}}\n"
)
USER_TOML = """[problem]
name = "u"
objective = "{mod}:fn"
[variables.a]
start = 1.0
lower = 0.0
upper = 2.0
[sweep]
kind = "grid"
points_per_dim = 3
"""


def _digest(d: Path) -> dict[str, str]:
    return {
        str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(d.rglob("*"))
        if p.is_file()
    }


def _run(args: list[str], cwd: Path, env: dict) -> tuple[int, str, str]:
    r = subprocess.run(
        [sys.executable, "-m", "encdesign", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    return r.returncode, (r.stderr.strip().splitlines() or [""])[0], r.stderr


def _closure(d: Path) -> Path:
    sys.path.insert(0, str(HERE / "tests"))
    from helpers import write_small_closure_recording  # pyright: ignore[reportMissingImports]

    return write_small_closure_recording(d / "R.toml").path


def probes() -> list[tuple[str, str, list[str], dict]]:
    """(class, name, argv, expectation) — expectation: ``exit`` (2), ``names`` (a word the
    first stderr line must hold), ``kept`` (inputs must stay intact)."""
    P = []
    ow = "input overwritten"
    for name, argv in [
        ("closure --json R.toml", ["calibrate", "closure", "R.toml", "--json", "R.toml"]),
        ("closure --json R.csv", ["calibrate", "closure", "R.toml", "--json", "R.csv"]),
        ("curve --table R.csv", ["calibrate", "curve", "R.toml", "--table", "R.csv"]),
        ("curve --table link", ["calibrate", "curve", "R.toml", "--table", "link.csv"]),
        ("curve --table hardlink", ["calibrate", "curve", "R.toml", "--table", "hard.csv"]),
        (
            "curve --table t --json t",
            ["calibrate", "curve", "R.toml", "--table", "t.csv", "--json", "t.csv"],
        ),
    ]:
        P.append((ow, name, argv, {"exit": 2}))
    cf = "computed then failed"
    for name, argv in [
        (
            "study --json <folder>",
            ["study", "run", "cramer", "--quick", "--out", "o1", "--json", "."],
        ),
        ("study --out <file>", ["study", "run", "cramer", "--quick", "--out", "R.toml"]),
    ]:
        P.append((cf, name, argv, {"exit": 2, "clean": ["o1"]}))
    ue = "user code ends the process"
    for name, at_import, in_fn in [
        ("sys.exit(0) at import", "sys.exit(0)", "pass"),
        ("sys.exit('msg') at import", "sys.exit('msg')", "pass"),
        ("KeyboardInterrupt at import", "raise KeyboardInterrupt", "pass"),
        ("sys.exit(0) in function", "", "sys.exit(0)"),
    ]:
        mod = "um_" + hashlib.md5(name.encode()).hexdigest()[:6]
        P.append(
            (
                ue,
                f"sweep: {name}",
                ["sweep", f"{mod}.toml", "--quiet"],
                {"exit": 2, "names": mod, "user": (mod, at_import, in_fn)},
            )
        )
    P.append(
        (
            ue,
            "diagnose --candidates sys.exit(0)",
            ["diagnose", "R.toml", "--json", "d.json", "--candidates", "exit0.py"],
            {"exit": 2, "names": "exit0.py"},
        )
    )
    sa = "silent acceptance / exit 3 / weak message"
    for name, argv, word in [
        (
            "curve --order -1",
            ["calibrate", "curve", "R.toml", "--table", "t.csv", "--order", "-1"],
            "--order",
        ),
        (
            "curve --points 10**9",
            ["calibrate", "curve", "R.toml", "--table", "t.csv", "--points", str(10**9)],
            "--points",
        ),
        (
            "curve --points 0",
            ["calibrate", "curve", "R.toml", "--table", "t.csv", "--points", "0"],
            "--points",
        ),
        (
            "curve --order 1000",
            ["calibrate", "curve", "R.toml", "--table", "t.csv", "--order", "1000"],
            "--order",
        ),
        (
            "curve --max-order -2",
            ["calibrate", "curve", "R.toml", "--table", "t.csv", "--max-order", "-2"],
            "--max-order",
        ),
        ("curve --table <folder>", ["calibrate", "curve", "R.toml", "--table", "."], "--table"),
        (
            "closure --sigma-arcsec 1e300",
            ["calibrate", "closure", "R.toml", "--sigma-arcsec", "1e300"],
            "--sigma-arcsec",
        ),
        (
            "cramer --seed 10**30",
            ["study", "run", "cramer", "--quick", "--out", "o2", "--seed", str(10**30)],
            "--seed",
        ),
        (
            "cramer --max-order 0",
            ["study", "run", "cramer", "--quick", "--out", "o2", "--max-order", "0"],
            "--max-order",
        ),
        (
            "cramer --max-order -1",
            ["study", "run", "cramer", "--quick", "--out", "o2", "--max-order", "-1"],
            "--max-order",
        ),
        (
            "cramer --max-order 10**6",
            ["study", "run", "cramer", "--quick", "--out", "o2", "--max-order", str(10**6)],
            "--max-order",
        ),
        (
            "closure study --instruments X",
            ["study", "run", "closure", "--quick", "--out", "o2", "--instruments", "X"],
            "--instruments",
        ),
        ("problem upper = 1e300 deg", ["sweep", "big.toml", "--quiet"], "upper"),
        ("problem name = 5", ["sweep", "name5.toml", "--quiet"], "name"),
        (
            "diagnose CANDIDATES = 5",
            ["diagnose", "R.toml", "--json", "d.json", "--candidates", "c5.py"],
            "CANDIDATES",
        ),
        (
            "sweep --resume NaN input",
            ["sweep", "ok.toml", "--resume", "nan.jsonl", "--quiet"],
            "nan.jsonl",
        ),
        (
            "sweep --resume tampered output",
            ["sweep", "ok.toml", "--resume", "tampered.jsonl", "--quiet"],
            "tampered.jsonl",
        ),
        (
            "sweep --resume binary file",
            ["sweep", "ok.toml", "--resume", "bin.jsonl", "--quiet"],
            "bin.jsonl",
        ),
    ]:
        P.append((sa, name, argv, {"exit": 2, "names": word}))
    fl = "file line numbers (item 3)"
    for name, argv, word in [
        ("moteus bad cell", ["import", "moteus", "m_cell.txt", "--out", "m.toml"], "line 9,"),
        ("moteus phase jump", ["import", "moteus", "m_jump.txt", "--out", "m.toml"], "line 9"),
        ("moteus 1_0 cell", ["import", "moteus", "m_sep.txt", "--out", "m.toml"], "line 9"),
        ("servo bad count", ["import", "servo", "s_cell.txt", "--out", "s.toml"], "line 9,"),
        ("magalpha 1e300", ["import", "magalpha", "a_big.csv", "--out", "a.toml"], "line 9"),
    ]:
        P.append((fl, name, argv, {"exit": 2, "names": word}))
    vb = "vector variable bounds (item 4)"
    for name, argv, word in [
        ("head_angles upper [.., 1e300, ..]", ["sweep", "v_upper.toml", "--quiet"], "[1].upper"),
        ("head_angles start [.., nan, ..]", ["sweep", "v_nan.toml", "--quiet"], "[1].start"),
        ("head_angles lower -1e300", ["sweep", "v_lower.toml", "--quiet"], "[0].lower"),
    ]:
        P.append((vb, name, argv, {"exit": 2, "names": word}))
    wf = "1e300: no warning, exit 2 (item 5)"
    for name, argv, word in [
        ("moteus cell 1e300", ["import", "moteus", "m_big.txt", "--out", "m.toml"], "line 9"),
        ("servo cell 1e300", ["import", "servo", "s_big.txt", "--out", "s.toml"], "line 9"),
        ("nmm cell 1e300", ["import", "nmm", "n_big.csv", "--out", "n.toml"], "line 9"),
        ("recording cell 1e300", ["calibrate", "closure", "big_rec.toml"], "line 9"),
        ("constraint lower 1e300", ["sweep", "c_big.toml", "--quiet"], "lower"),
        ("yield spec 1e300", ["sweep", "y_big.toml", "--quiet"], "spec"),
        ("driver rtol 1e300", ["optimize", "r_big.toml", "--quiet"], "rtol"),
        (
            "--fresh-replicates 1e300",
            ["optimize", "ok.toml", "--fresh-replicates", "1e300"],
            "--fresh",
        ),
        ("--processes 1e300", ["sweep", "ok.toml", "--processes", "1e300"], "--processes"),
        ("--phi-deg 1e300", ["sds", "simulate", "--out", "s.toml", "--phi-deg", "1e300"], "--phi"),
    ]:
        P.append((wf, name, argv, {"exit": 2, "names": word, "warnings": True}))
    return P


def _edit_line(src: Path, dst: Path, line: int, text: str) -> None:
    """Copy ``src`` to ``dst`` with file line ``line`` (1-based) replaced by ``text``."""
    lines = src.read_text().splitlines()
    lines[line - 1] = text
    dst.write_text("\n".join(lines) + "\n")


def _item_files(d: Path) -> None:
    """Inputs of the probes of items 3-5: a bad value on file line 9 of each source (the
    moteus file gets a comment and blank lines, so data row and file line differ)."""
    real = Path("/work/shared/realdata")
    mot = real / "moteus_encoder_cal.txt"
    body = mot.read_text().splitlines()[:40]
    m = d / "m0.txt"
    m.write_text("\n".join(body[:3] + ["", "# a comment", ""] + body[3:]) + "\n")
    _edit_line(m, d / "m_cell.txt", 9, "1 9100 70000")
    _edit_line(m, d / "m_jump.txt", 9, "1 50000 35596")
    _edit_line(m, d / "m_sep.txt", 9, "1 9_100 35596")
    _edit_line(m, d / "m_big.txt", 9, "1 9100 1e300")
    srv = d / "s0.txt"
    lines = (real / "servo_optical_encoder_capture.txt").read_text().splitlines()[:60]
    srv.write_text("\n".join(["# t A B position cost", "", *lines]) + "\n")
    t = lines[6].split()
    _edit_line(srv, d / "s_cell.txt", 9, " ".join([t[0], "5702.5", *t[2:]]))
    _edit_line(srv, d / "s_big.txt", 9, " ".join([t[0], "1e300", *t[2:]]))
    mag = d / "a0.csv"
    lines = (real / "magalpha_calibration_example.csv").read_text().splitlines()[:60]
    mag.write_text("\n".join([lines[0], "", *lines[1:]]) + "\n")
    _edit_line(mag, d / "a_big.csv", 9, "1e300,0.5")
    nmm = d / "n0.csv"
    nmm.write_text("\n".join((real / "nmm_X_raw.csv").read_text().splitlines()[:60]) + "\n")
    _edit_line(nmm, d / "n_big.csv", 9, "1.0, 1e300, 1.0")
    table = (d / "R.csv").read_text().splitlines()
    cells = table[8].split(",")
    cells[-1] = "1e300"
    table[8] = ",".join(cells)
    (d / "big_rec.csv").write_text("\n".join(table) + "\n")
    rec = (d / "R.toml").read_text().replace('"R.csv"', '"big_rec.csv"')
    (d / "big_rec.toml").write_text(rec)
    head = (HERE / "examples" / "head_layout_3.toml").read_text()
    (d / "v_upper.toml").write_text(head.replace("upper = 370.0", "upper = [370.0, 1e300, 370.0]"))
    (d / "v_nan.toml").write_text(head.replace("[0.0, 100.0, 250.0]", "[0.0, nan, 250.0]"))
    (d / "v_lower.toml").write_text(head.replace("lower = -10.0", "lower = -1e300"))
    tol = (HERE / "examples" / "tolerance_cost_3p1.toml").read_text()
    (d / "c_big.toml").write_text(tol.replace("lower = 0.99", "lower = 1e300"))
    (d / "y_big.toml").write_text(tol.replace("spec = 1.0", "spec = 1e300"))
    (d / "r_big.toml").write_text(tol.replace("rtol = 1e-4", "rtol = 1e300"))


def setup(d: Path, env: dict) -> None:
    rec = _closure(d)
    assert rec.name == "R.toml"
    os.symlink("R.csv", d / "link.csv")
    os.link(d / "R.csv", d / "hard.csv")
    (d / "ok.toml").write_text(SWEEP.format(name='"ok"', upper="28.0"))
    (d / "big.toml").write_text(SWEEP.format(name='"big"', upper="1e300"))
    (d / "name5.toml").write_text(SWEEP.format(name="5", upper="28.0"))
    (d / "c5.py").write_text("CANDIDATES = 5\n")
    (d / "exit0.py").write_text("import sys\nsys.exit(0)\n")
    for _, _, _, exp in probes():
        if "user" in exp:
            mod, at_import, in_fn = exp["user"]
            (d / f"{mod}.py").write_text(USER_MOD.format(at_import=at_import, in_fn=in_fn))
            (d / f"{mod}.toml").write_text(USER_TOML.format(mod=mod))
    _item_files(d)
    rc, err, _ = _run(["sweep", "ok.toml", "--cases", "full.jsonl", "--quiet"], d, env)
    assert rc == 0, err
    lines = (d / "full.jsonl").read_text().splitlines()
    first = json.loads(lines[0])
    nan = dict(first, inputs={k: None for k in first["inputs"]})
    (d / "nan.jsonl").write_text(json.dumps(nan) + "\n" + "\n".join(lines[1:]) + "\n")
    tam = dict(first, outputs={k: 12345.0 for k in first["outputs"]})
    (d / "tampered.jsonl").write_text(json.dumps(tam) + "\n" + "\n".join(lines[1:]) + "\n")
    (d / "bin.jsonl").write_bytes(bytes(range(256)) * 4)
    (d / "full.jsonl").unlink()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", default=os.environ.get("PYTHONPATH", str(HERE)))
    ap.add_argument("--only", default=None, help="run only probes whose name holds this")
    a = ap.parse_args(argv)
    env = dict(os.environ, PYTHONWARNINGS="ignore", JAX_PLATFORMS="cpu")
    bad: dict[str, int] = {}
    total: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        base = root / "base"
        base.mkdir()
        setup(base, env)
        for cls, name, args, exp in probes():
            if a.only and a.only not in name:
                continue
            d = root / hashlib.md5(name.encode()).hexdigest()[:8]
            subprocess.run(["cp", "-a", str(base), str(d)], check=True)
            before = _digest(d)
            penv = dict(env, PYTHONWARNINGS="default") if exp.get("warnings") else env
            rc, err, full = _run(args, d, penv)
            after = _digest(d)
            problems = []
            changed = [k for k in before if before[k] != after.get(k)]
            if changed:
                problems.append(f"changed {changed}")
            left = sorted(set(after) - set(before))
            if rc != 0 and left:
                problems.append(f"left {left}")
            if rc != exp["exit"]:
                problems.append(f"exit {rc}")
            if "names" in exp and exp["names"].lower() not in err.lower():
                problems.append("message does not name it")
            if err.startswith(("/", "<")) and "Warning" in err:
                problems.append("warning first")
            if exp.get("warnings") and "Warning" in full:
                problems.append("a warning printed")
            total[cls] = total.get(cls, 0) + 1
            if problems:
                bad[cls] = bad.get(cls, 0) + 1
            flag = "BAD " if problems else "ok  "
            print(f"{flag}[{cls}] {name}: exit {rc}; {'; '.join(problems)} | {err[:140]}")
    print(f"\ntree {a.tree}")
    for cls in total:
        print(f"{cls:45s} {bad.get(cls, 0)} of {total[cls]} mishandled")
    return 0


if __name__ == "__main__":
    sys.exit(main())
