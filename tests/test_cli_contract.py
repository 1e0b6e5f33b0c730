"""Each command against the CLI contract (docs/cli-contract.md): exit codes and the
missing-parent policy.

One row per command (every sub-command ``encdesign --help`` lists, every action of a
command with actions, every ``import`` source, ``study list`` and every ``study run NAME``);
a test compares the table with the parsers, so a new command without a row fails. Each row:

* ``bad``: an input refused before any computation: exit 2, one line on stderr naming
  the flag or key, nothing written or changed;
* ``parent``: outputs under folders that do not exist yet. The policy is that missing parent
  folders are created: the run exits 0 and writes ``made``; or, where a full run is not
  cheap, its input is refused inside the output guard (exit 2 naming ``refuse``, an input,
  not the output) and the folders the guard would have created are removed again.

Studies: the outputs under missing parents are accepted when the flags are parsed (the
study's parser is captured, nothing runs), and one study (``cramer --quick``) is run.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from test_guard import DESIGN, PROBLEM

from encdesign.cli._main import OneLineParser, _command_modules, available_studies, main
from encdesign.io import _study

REALDATA = Path("/work/shared/realdata")


@dataclass(frozen=True)
class Row:
    """``bad``: argv (after the command) refused before any work, naming ``names``;
    ``parent``: argv writing under ``{w}/new/…``; ``made``: what it writes (exit 0), or
    ``refuse``: the input it refuses (exit 2) after the guard accepted the outputs."""

    bad: tuple[str, ...]
    names: str
    parent: tuple[str, ...] | None = None
    made: tuple[str, ...] = ()
    refuse: str | None = None


N = "{w}/new"
REC = "{w}/rec.toml"
ROWS: dict[tuple[str, ...], Row] = {
    ("simulate",): Row(
        ("{w}/design.toml", "--out", "{w}/o.toml", "--seed", "-1"),
        "--seed",
        ("{w}/design.toml", "--out", f"{N}/a/r.toml"),
        ("new/a/r.toml", "new/a/r.csv"),
    ),
    ("conceal",): Row(
        ("{w}/c.toml", "--amplitude", "1e300"),
        "--amplitude",
        (f"{N}/a/c.toml", "--samples-per-run", "64", "--truth", f"{N}/b/t.json"),
        ("new/a/c.toml", "new/a/c.csv", "new/b/t.json"),
    ),
    ("diagnose",): Row(
        (REC, "--json", "{w}/d.json", "--max-effects", "101"),
        "--max-effects",
        ("{w}/garbage.toml", "--json", f"{N}/a/d.json", "--report", f"{N}/b/r.txt"),
        refuse="garbage.toml",
    ),
    ("check-gradients",): Row(
        ("{w}/p.toml", "--rtol", "0"),
        "--rtol",
        ("{w}/p.toml", "--json", f"{N}/a/g.json"),
        ("new/a/g.json",),
    ),
    ("optimize",): Row(
        ("{w}/p.toml", "--fresh-replicates", "1_0"),
        "--fresh-replicates",
        ("{w}/p.toml", "--json", f"{N}/a/o.json", "--cases", f"{N}/b/c.jsonl", "--quiet"),
        ("new/a/o.json", "new/b/c.jsonl"),
    ),
    ("sweep",): Row(
        ("{w}/p.toml", "--kind", "spiral"),
        "--kind",
        ("{w}/p.toml", "--cases", f"{N}/a/c.csv", "--quiet"),
        ("new/a/c.csv",),
    ),
    ("sds", "simulate"): Row(
        ("simulate", "--out", "{w}/s.toml", "--marks", "1"),
        "--marks",
        ("simulate", "--out", f"{N}/a/s.toml", "--marks", "40", "--revs", "1", "--phi-deg", "0"),
        ("new/a/s.toml", "new/a/s.csv"),
    ),
    ("sds", "measure"): Row(
        ("measure", "{w}/sds.toml", "--revs-per-reading", "0"),
        "--revs-per-reading",
        ("measure", "{w}/sds.toml", "--json", f"{N}/a/m.json"),
        ("new/a/m.json",),
    ),
    ("calibrate", "closure"): Row(
        ("closure", "{w}/cl.toml", "--sigma-arcsec", "0"),
        "--sigma-arcsec",
        ("closure", "{w}/cl.toml", "--json", f"{N}/a/c.json"),
        ("new/a/c.json",),
    ),
    ("calibrate", "curve"): Row(
        ("curve", "{w}/cl.toml", "--table", "{w}/t.csv", "--points", "3"),
        "--points",
        ("curve", "{w}/cl.toml", "--table", f"{N}/a/t.csv", "--json", f"{N}/b/k.json"),
        ("new/a/t.csv", "new/b/k.json"),
    ),
    ("study", "list"): Row(("list", "extra"), "extra"),
}
for _src, _file in [
    ("nmm", "nmm_X_raw.csv"),
    ("odrive", "odrive.npy"),
    ("moteus", "moteus.txt"),
    ("magalpha", "magalpha.csv"),
    ("servo", "servo.txt"),
]:
    ROWS[("import", _src)] = Row(
        (_src, f"{{w}}/{_file}", "--out", "{w}"),
        "--out",
        (_src, f"{{w}}/{_file}", "--out", f"{N}/a/{_src}.toml"),
        (f"new/a/{_src}.toml", f"new/a/{_src}.csv"),
    )
ROWS[("import", "realdata")] = Row(
    ("realdata", "{w}/nmm_X_raw.csv", "--out", f"{N}/r"),
    "SRC",
    ("realdata", "{w}/real", "--out", f"{N}/a/r"),
    ("new/a/r/nmm_x.toml", "new/a/r/odrive_comp_1.toml", "new/a/r/servo_optical.toml"),
)
STUDIES = sorted(available_studies())
for _name in STUDIES:
    ROWS[("study", "run", _name)] = Row(("run", _name, "--seed", "-1"), "--seed")


# ----------------------------------------------------------------------------- the parsers


def _leaves(parser: argparse.ArgumentParser) -> list[tuple[str, ...]]:
    """Command paths below ``parser``: its sub-parsers' actions, or the choices of a first
    positional argument that selects what the command does (``import SOURCE``)."""
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return [(k, *rest) for k, sub in a.choices.items() for rest in _leaves(sub)]
    pos = [a for a in parser._actions if not a.option_strings]
    if pos and pos[0].choices:
        return [(str(c),) for c in pos[0].choices]
    return [()]


def parser_commands() -> set[tuple[str, ...]]:
    """Every command path the parsers accept (``study`` is built in)."""
    out = {("study", "list")} | {("study", "run", s) for s in available_studies()}
    for name, modname in _command_modules().items():
        p = OneLineParser(prog=f"encdesign {name}")
        importlib.import_module(modname).configure(p)
        out |= {(name, *rest) for rest in _leaves(p)}
    return out


def test_the_table_has_a_row_for_every_command(capsys):
    assert main(["--help"]) == 0
    listed = {ln.split()[0] for ln in capsys.readouterr().out.splitlines()[3:] if ln.strip()}
    assert listed == {"study", *_command_modules()}
    assert {c[0] for c in parser_commands()} == listed
    assert set(ROWS) == parser_commands()


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Path:
    """Small inputs of every command: design, recording, problem, sds and closure
    recordings, a source of every importer, a small realdata folder."""
    d = tmp_path_factory.mktemp("contract")
    (d / "design.toml").write_text(DESIGN)
    (d / "p.toml").write_text(PROBLEM)
    (d / "garbage.toml").write_text("this is = not [ a recording\n")
    assert main(["simulate", str(d / "design.toml"), "--out", str(d / "rec.toml")]) == 0
    sds = ["sds", "simulate", "--out", str(d / "sds.toml"), "--marks", "60", "--revs", "1"]
    assert main([*sds, "--phi-deg", "0", "90"]) == 0
    _closure(d / "cl.toml")
    phase = np.linspace(0.0, 359.0, 360)
    rows = "\n".join(f"{p!r},{1000.0 + np.sin(p):.6f},0.1" for p in phase.tolist())
    (d / "nmm_X_raw.csv").write_text("Phase (deg),Radius,Roundness deviation\n" + rows + "\n")
    t = np.linspace(0.0, 10.0, 500)
    np.save(d / "odrive.npy", np.stack([t, 819.2 * t, 0.1 * np.sin(t)]))
    for src, dst, n in [
        ("moteus_encoder_cal.txt", "moteus.txt", 60),
        ("magalpha_calibration_example.csv", "magalpha.csv", 60),
        ("servo_optical_encoder_capture.txt", "servo.txt", 120),
    ]:
        lines = (REALDATA / src).read_text().splitlines()[:n]
        (d / dst).write_text("\n".join(lines) + "\n")
    real = d / "real"
    real.mkdir()
    for name in REALDATA.iterdir():
        if name.suffix == ".npy":
            a = np.load(name)
            np.save(real / name.name, a[:, :400] if a.ndim == 2 else a)
        elif name.suffix in (".csv", ".txt"):
            lines = name.read_text().splitlines()[:120]
            (real / name.name).write_text("\n".join(lines) + "\n")
    return d


def _closure(path: Path) -> None:
    from helpers import write_small_closure_recording

    write_small_closure_recording(path)


@pytest.fixture
def work(bench, tmp_path) -> Path:
    w = tmp_path / "w"
    shutil.copytree(bench, w)
    return w


def _snapshot(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): "<dir>"
        if p.is_dir()
        else hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
    }


def _argv(cmd: tuple[str, ...], rest: tuple[str, ...], w: Path) -> list[str]:
    return [cmd[0], *(a.format(w=w) for a in rest)]


# ----------------------------------------------------------------------------- the contract


@pytest.mark.parametrize("cmd", sorted(ROWS), ids=" ".join)
def test_bad_input_exits_2_naming_it_and_leaves_nothing(work, capsys, cmd):
    row = ROWS[cmd]
    before = _snapshot(work)
    rc = main(_argv(cmd, row.bad, work))
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert row.names in lines[0], err
    assert _snapshot(work) == before


PARENT = sorted(c for c, r in ROWS.items() if r.parent is not None)


@pytest.mark.parametrize("cmd", PARENT, ids=" ".join)
def test_outputs_under_a_missing_parent_follow_the_policy(work, capsys, cmd):
    row = ROWS[cmd]
    assert row.parent is not None
    before = _snapshot(work)
    rc = main(_argv(cmd, row.parent, work))
    err = capsys.readouterr().err
    if row.refuse is not None:  # refused on its input inside the guard: nothing left
        assert rc == 2, err
        assert row.refuse in err and "new" not in err, err
        assert _snapshot(work) == before
        return
    assert rc == 0, err
    for f in row.made:
        assert (work / f).is_file(), f
    left = set(_snapshot(work)) - set(before)
    assert all(p == "new" or p.startswith("new/") for p in left), left


class _Captured(Exception):
    def __init__(self, parser):
        super().__init__("captured")
        self.parser = parser


def study_parser_of(name: str, monkeypatch) -> argparse.ArgumentParser:
    """The study's argument parser, captured when its ``main`` parses (nothing runs)."""
    from encdesign.cli._main import _load_study

    def capture(self, args=None, namespace=None):
        raise _Captured(self)

    mod = _load_study(name)
    with monkeypatch.context() as m:
        m.setattr(_study._StudyParser, "parse_args", capture)
        with pytest.raises(_Captured) as e:
            mod.main([])
    return e.value.parser


@pytest.mark.parametrize("name", STUDIES)
def test_study_outputs_under_a_missing_parent_accepted_when_parsed(tmp_path, monkeypatch, name):
    p = study_parser_of(name, monkeypatch)
    out, js = tmp_path / "new/a/out", tmp_path / "new/b/s.json"
    ns = p.parse_args(["--out", str(out), "--json", str(js), "--quick"])
    assert Path(ns.out) == out and Path(ns.json) == js
    assert not (tmp_path / "new").exists()  # checked, not created, before the study runs


def test_a_study_creates_its_missing_parents(tmp_path, capsys):
    out, js = tmp_path / "new/a/out", tmp_path / "new/b/s.json"
    argv = ["study", "run", "cramer", "--quick", "--no-plots", "--out", str(out)]
    assert main([*argv, "--json", str(js)]) == 0, capsys.readouterr().err
    assert (out / "cramer.json").is_file() and js.is_file()
