"""Property-based tests (hypothesis) of every reader and of the command-line checks (issue 12).

The property everywhere: bad input is refused with one line (an
:class:`~encdesign.EncdesignInputError`, exit status 2) or the input is read correctly —
never another exception, a partial file or a changed input. Examples are derandomised
(the same on every run, so CI is reproducible) and the whole module runs in well under
two minutes.
"""

from __future__ import annotations

import contextlib
import gzip
import hashlib
import io
import math
import tempfile
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from encdesign._errors import EncdesignInputError
from encdesign.cli._main import OneLineParser, main
from encdesign.design._design import parse_design
from encdesign.design._problem import parse_problem
from encdesign.io._recording import KINDS, load_recording
from encdesign.io._table import read_columns

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

FUZZ = settings(
    max_examples=120,
    deadline=None,
    database=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

# values a user might put anywhere: wrong types, non-finite, absurd, edge integers
ODD_VALUES = st.one_of(
    st.sampled_from(
        [0, -1, 1, 2**63, 2**64, -(2**70), 0.0, -0.0, -1.0, 1e300, -1e300, 1e-300, math.nan]
        + [math.inf, -math.inf, True, False, "", "x", "nan", [], [1.0], {}, {"a": 1}]
    ),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.text(max_size=8),
    st.lists(st.floats(allow_nan=False, width=32), max_size=5),
)


def _one_line(exc: BaseException) -> None:
    msg = str(exc)
    assert msg and "\n" not in msg, msg
    assert "np.float64(" not in msg and "Traceback" not in msg, msg


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def scratch() -> Path:
    with tempfile.TemporaryDirectory(prefix="encdesign-fuzz-") as d:
        yield Path(d)


# ----------------------------------------------------------------------------- CSV reader


@FUZZ
@given(st.binary(max_size=400), st.sampled_from(["t.csv", "t.csv.gz"]))
def test_csv_reader_never_crashes_on_bytes(scratch, data, name):
    path = scratch / name
    path.write_bytes(data)
    before = _digest(path)
    try:
        header, cols, _ = read_columns(path)
    except EncdesignInputError as exc:
        _one_line(exc)
        assert str(path) in str(exc)
    else:
        assert len({len(c) for c in cols.values()} | {0}) <= 2
        assert list(cols) == header
    assert _digest(path) == before


@st.composite
def tables(draw):
    n_cols = draw(st.integers(1, 4))
    names = draw(st.permutations(["t", "run", "h0", "h1", "x"]))[:n_cols]
    n_rows = draw(st.integers(1, 12))
    cols = {}
    for name in names:
        if name == "run":
            vals = draw(
                st.lists(st.integers(-(2**63), 2**63 - 1), min_size=n_rows, max_size=n_rows)
            )
        else:
            vals = draw(
                st.lists(
                    st.floats(allow_nan=False, allow_infinity=False),
                    min_size=n_rows,
                    max_size=n_rows,
                )
            )
        cols[name] = vals
    style = {
        "bom": draw(st.booleans()),
        "crlf": draw(st.booleans()),
        "trailing": draw(st.booleans()),
        "gzip": draw(st.booleans()),
        "blank": draw(st.lists(st.integers(0, n_rows + 1), max_size=3)),
    }
    return names, cols, style


def _render(names, cols, style) -> tuple[bytes, list[int]]:
    """The CSV bytes and the file line of every data row."""
    lines = [",".join(names)]
    for i in range(len(cols[names[0]])):
        lines.append(",".join(repr(cols[n][i]) for n in names))
    if style["trailing"]:
        lines = [s + "," for s in lines]
    row_lines = []
    out = []
    for k, s in enumerate(lines):
        out += [""] * style["blank"].count(k)
        out.append(s)
        if k > 0:
            row_lines.append(len(out))
    nl = "\r\n" if style["crlf"] else "\n"
    text = ("\ufeff" if style["bom"] else "") + nl.join(out) + nl
    data = text.encode()
    return (gzip.compress(data) if style["gzip"] else data), row_lines


@FUZZ
@given(tables(), st.data())
def test_csv_reader_reads_every_style_exactly(scratch, table, data):
    names, cols, style = table
    blob, row_lines = _render(names, cols, style)
    path = scratch / "s.csv"
    path.write_bytes(blob)
    header, got, ref = read_columns(path)
    assert header == names
    for n in names:
        expect = np.asarray(cols[n], dtype=np.int64 if n == "run" else np.float64)
        assert got[n].dtype == expect.dtype
        assert np.array_equal(got[n], expect)
    assert [ref.line(i) for i in range(len(row_lines))] == row_lines
    # one bad cell: refused naming its true line and column
    i = data.draw(st.integers(0, len(row_lines) - 1))
    col = data.draw(st.sampled_from(names))
    cols2 = {n: list(v) for n, v in cols.items()}
    cols2[col][i] = "x1"
    blob2, _ = _render(names, cols2, style)
    path.write_bytes(blob2)
    with pytest.raises(EncdesignInputError) as e:
        read_columns(path)
    _one_line(e.value)
    assert f"line {row_lines[i]}, column '{col}'" in str(e.value)


# ----------------------------------------------------------------------------- recordings

RECORDINGS = {
    "multihead": (
        {"encoder": {"optical_radius_m": 0.0254, "head_angles_deg": [0.0, 180.0]}},
        "t,run,h0,h1\n0.0,0,0.0,0.0\n0.5,0,3.1,3.2\n1.0,1,6.2,6.3\n",
    ),
    "sds": (
        {
            "encoder": {
                "marks_per_rev": 2,
                "fixed_sensor_angles_deg": [0.0],
                "moving_sensor_angles_deg": [0.0],
            }
        },
        "run,sensor,mark,t\n0,f0,0,0.0\n0,m0,0,0.1\n0,f0,1,0.5\n0,m0,1,0.6\n",
    ),
    "quadrature": (
        {"encoder": {"signal_period_m": 2e-5}},
        "sa,sb\n1.0,0.0\n0.0,1.0\n-1.0,0.0\n",
    ),
    "motion": (
        {"encoder": {"counts_per_rev": 8192}, "motor": {"pole_pairs": 7, "stator_slots": 12}},
        "t,counts,current_a\n0.0,0.0,0.1\n0.1,10.0,0.2\n0.2,20.0,0.1\n",
    ),
}


def _paths_in(meta: dict, prefix: tuple = ()) -> list[tuple]:
    out = []
    for k, v in meta.items():
        out.append((*prefix, k))
        if isinstance(v, dict):
            out += _paths_in(v, (*prefix, k))
    return out


def _set(meta: dict, path: tuple, value) -> dict:
    import copy

    m = copy.deepcopy(meta)
    d = m
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value
    return m


@FUZZ
@given(st.sampled_from(sorted(RECORDINGS)), st.data(), ODD_VALUES)
def test_recording_loader_reads_or_refuses(scratch, kind, data, value):
    base, csv = RECORDINGS[kind]
    meta = {"format": "encdesign-recording/1", "kind": kind, "data": "r.csv", **base}
    where = data.draw(st.sampled_from(_paths_in(meta) + [("encoder", "extra_key")]))
    meta = _set(meta, where, value)
    toml, table = scratch / "r.toml", scratch / "r.csv"
    try:
        toml.write_text(tomli_w.dumps(meta))
    except (TypeError, ValueError):  # not representable in TOML at all
        return
    table.write_text(csv)
    before = (_digest(toml), _digest(table))
    try:
        rec = load_recording(toml)
    except EncdesignInputError as exc:
        _one_line(exc)
        assert str(scratch) in str(exc)
    else:
        assert rec.kind in KINDS
        for v in rec.encoder.values():
            for x in v if isinstance(v, list) else [v]:
                assert isinstance(x, int | float) and math.isfinite(x) and abs(x) < 1e16
    assert (_digest(toml), _digest(table)) == before


# ----------------------------------------------------------------------------- designs

DESIGN = tomllib.loads((EXAMPLES / "design-3plus1.toml").read_text())


@FUZZ
@given(st.data(), ODD_VALUES)
def test_design_parser_reads_or_refuses(data, value):
    where = data.draw(st.sampled_from(_paths_in(DESIGN) + [("disk", "unknown")]))
    raw = _set(DESIGN, where, value)
    runs = raw.get("bench", {}).get("runs") if isinstance(raw.get("bench"), dict) else None
    if isinstance(runs, list) and runs and isinstance(runs[0], dict) and data.draw(st.booleans()):
        key = data.draw(st.sampled_from(["speed_rev_per_s", "end_time_s", "sample_rate_hz"]))
        runs[0][key] = value  # a value inside a bench run
    try:
        d = parse_design(raw, "d.toml")
    except EncdesignInputError as exc:
        _one_line(exc)
        assert "d.toml" in str(exc)
    else:
        assert 0 < float(d.model.disk.optical_radius_m) <= 10
        for r in d.runs:
            assert abs(r.speed_rev_per_s) <= 1e4 and r.sample_rate_hz <= 1e9
            assert 2 <= r.n_samples <= 20_000_000


# ----------------------------------------------------------------------------- problems

PROBLEMS = {
    p.name: tomllib.loads(p.read_text())
    for p in sorted(EXAMPLES.glob("*.toml"))
    if "problem" in tomllib.loads(p.read_text())
}


@FUZZ
@given(st.sampled_from(sorted(PROBLEMS)), st.data(), ODD_VALUES)
def test_problem_parser_reads_or_refuses(name, data, value):
    raw = PROBLEMS[name]
    where = data.draw(st.sampled_from(_paths_in(raw) + [("model", "radius_m"), ("driver",)]))
    raw = _set(raw, where, value)
    try:
        p = parse_problem(raw, source="p.toml")
    except EncdesignInputError as exc:
        _one_line(exc)
        assert "p.toml" in str(exc)
    else:
        for k, v in p.model.items():
            if isinstance(v, float):
                assert math.isfinite(v), k
        assert 0 <= p.seed < 2**63


# ----------------------------------------------------------------------------- CLI flags

# command, required arguments, flag, range it must come back in (None: free)
FLAGS = [
    ("simulate", ["d.toml", "--out", "o.toml"], "--seed", (0, 2**63 - 1)),
    ("conceal", ["o.toml"], "--seed", (0, 2**63 - 1)),
    ("conceal", ["o.toml"], "--samples-per-run", (16, 10_000_000)),
    ("conceal", ["o.toml"], "--amplitude", (0.0, 1e4)),
    ("check-gradients", ["p.toml"], "--rel-step", (0.0, 0.1)),
    ("check-gradients", ["p.toml"], "--rtol", (0.0, 1.0)),
    ("diagnose", ["r.toml", "--json", "o.json"], "--max-order", (1, 100_000)),
    ("sds", ["simulate", "--out", "o.toml"], "--marks", (2, 10_000_000)),
    ("sds", ["simulate", "--out", "o.toml"], "--revs", (1, 100_000)),
    ("sds", ["simulate", "--out", "o.toml"], "--pole-pairs", (1, 1000)),
    ("sds", ["simulate", "--out", "o.toml"], "--phi-deg", (-1e6, 1e6)),
    ("sds", ["measure", "r.toml"], "--revs-per-reading", (1, 100_000)),
]

FLAG_TEXT = st.one_of(
    st.integers(-(2**70), 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["nan", "inf", "-inf", "1e300", "-0", "0", "0x10", "1_000", "", " 3"]),
    st.text(max_size=6),
)


@FUZZ
@given(st.sampled_from(FLAGS), FLAG_TEXT)
def test_cli_flags_parse_in_range_or_refuse_in_one_line(flag_case, text):
    import importlib

    cmd, required, flag, (lo, hi) = flag_case
    mod = importlib.import_module(f"encdesign.cli._{cmd.replace('-', '_')}")
    parser = OneLineParser(prog=f"encdesign {cmd}")
    mod.configure(parser)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            args = parser.parse_args([*required, f"{flag}={text}"])
        except SystemExit as exc:
            assert exc.code == 2
            lines = err.getvalue().strip().splitlines()
            assert len(lines) == 1, err.getvalue()
            return
    value = getattr(args, flag.lstrip("-").replace("-", "_"))
    for v in value if isinstance(value, list) else [value]:
        assert lo <= v <= hi and math.isfinite(v)


# ----------------------------------------------------------------------------- end to end

SMALL_DESIGN = {
    "format": "encdesign-design/1",
    "disk": {"optical_radius_m": 0.0254, "eccentricity_m": [5e-6, 0.0]},
    "heads": {"angles_deg": [0.0, 120.0, 240.0, 22.0], "reference_head": 3, "noise_rad": 1e-7},
    "bench": {"runs": [{"speed_rev_per_s": 1.0, "end_time_s": 1.0, "sample_rate_hz": 128.0}]},
}


@settings(FUZZ, max_examples=25)
@given(st.data(), ODD_VALUES)
def test_simulate_end_to_end_refuses_or_writes_a_loadable_recording(scratch, data, value):
    where = data.draw(st.sampled_from(_paths_in(SMALL_DESIGN)))
    raw = _set(SMALL_DESIGN, where, value)
    d = scratch / "e2e"
    d.mkdir(exist_ok=True)
    for f in d.iterdir():
        f.unlink()
    design = d / "design.toml"
    try:
        design.write_text(tomli_w.dumps(raw))
    except (TypeError, ValueError):
        return
    before = _digest(design)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(["simulate", str(design), "--out", str(d / "out.toml")])
    assert _digest(design) == before
    names = sorted(p.name for p in d.iterdir())
    if rc == 2:
        assert len(err.getvalue().strip().splitlines()) == 1, err.getvalue()
        assert names == ["design.toml"], names
    else:
        assert rc == 0, err.getvalue()
        assert names == ["design.toml", "out.csv", "out.toml"], names
        assert load_recording(d / "out.toml").n_rows > 0
