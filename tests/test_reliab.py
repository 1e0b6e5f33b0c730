"""The CLI's reliability contract (docs/cli-contract.md): checked numbers, user code under
a guard, verified resumes, outputs checked before any work."""

from __future__ import annotations

import argparse
import json
import math
import os
import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from encdesign import EncdesignInputError
from encdesign._checks import SEED_MAX, float_arg, int_arg
from encdesign._usercode import guarded, user_code
from encdesign.design._cases import Case, read_cases, verify_case, write_cases
from encdesign.io._study import study_parser

FEW = settings(max_examples=60, derandomize=True, deadline=None)


@FEW
@given(st.one_of(st.text(max_size=12), st.integers().map(str), st.floats().map(repr)))
def test_int_arg_returns_in_range_or_refuses(text):
    parse = int_arg(1, 1000)
    try:
        v = parse(text)
    except argparse.ArgumentTypeError:
        return
    assert isinstance(v, int) and 1 <= v <= 1000 and "_" not in text


@FEW
@given(st.one_of(st.text(max_size=12), st.floats().map(repr), st.integers().map(str)))
def test_float_arg_returns_finite_in_range_or_refuses(text):
    parse = float_arg(0.0, 1e6, lower_open=True)
    try:
        v = parse(text)
    except argparse.ArgumentTypeError:
        return
    assert math.isfinite(v) and 0.0 < v <= 1e6 and "_" not in text


@pytest.mark.parametrize("text", ["1_0", "0x10", "nan", "inf", str(SEED_MAX + 1), ""])
def test_literals_and_out_of_range_are_refused(text):
    with pytest.raises(argparse.ArgumentTypeError):
        int_arg(0, SEED_MAX)(text)


@pytest.mark.parametrize(
    "exc", [SystemExit(0), SystemExit("msg"), KeyboardInterrupt(), RuntimeError("boom")]
)
def test_user_code_becomes_input_error_naming_it(exc):
    def fn():
        raise exc

    with pytest.raises(EncdesignInputError, match="my_mod:fn"):
        guarded("objective 'my_mod:fn'", fn)()
    with pytest.raises(EncdesignInputError, match="my_mod"), user_code("module 'my_mod'"):
        raise exc


def test_user_code_lets_kept_errors_through():
    with pytest.raises(ValueError), user_code("m", keep=(ValueError,)):
        raise ValueError("kept")


def _cases(tmp_path, suffix):
    p = tmp_path / f"c{suffix}"
    write_cases(p, [Case(i, {"x": 0.1 * i}, {"f": float(i)}, "success", 1) for i in range(3)])
    return p


@pytest.mark.parametrize("suffix", [".jsonl", ".csv"])
def test_resume_refuses_a_tampered_case(tmp_path, suffix):
    p = _cases(tmp_path, suffix)
    for c in read_cases(p):
        verify_case(c, p)
    p.write_text(p.read_text().replace("2.0", "2.5"))
    with pytest.raises(EncdesignInputError, match="checksum"):
        for c in read_cases(p):
            verify_case(c, p)


def test_resume_refuses_non_finite_and_out_of_bounds_inputs(tmp_path):
    class V:
        name, lower, upper = "x", 0.0, 0.15

    class P:
        continuous = (V,)

    p = _cases(tmp_path, ".jsonl")
    cs = read_cases(p)
    with pytest.raises(EncdesignInputError, match="outside the problem's bounds"):
        for c in cs:
            verify_case(c, p, P)
    lines = p.read_text().splitlines()
    d = json.loads(lines[0])
    d["inputs"]["x"] = None
    p.write_text(json.dumps(d) + "\n")
    with pytest.raises(EncdesignInputError):
        verify_case(read_cases(p)[0], p)


def test_resume_refuses_a_binary_file(tmp_path):
    p = tmp_path / "b.jsonl"
    p.write_bytes(bytes(range(256)))
    with pytest.raises(EncdesignInputError, match="not a text file"):
        read_cases(p)


def test_study_flags_and_outputs_checked_when_parsed(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    p = study_parser("demo", "A demo.")
    p.add_argument("--n", type=int, default=1)
    for argv in (
        ["--out", str(f)],
        ["--out", str(tmp_path / "o"), "--json", str(tmp_path)],
        ["--seed", str(10**30)],
        ["--n", "0"],
        ["--n", "1_0"],
    ):
        with pytest.raises(SystemExit) as e:
            p.parse_args(argv)
        assert e.value.code == 2
    assert not os.path.exists(tmp_path / "o")
    assert p.parse_args(["--out", str(tmp_path / "o"), "--n", "5"]).n == 5


def test_csv_cell_with_digit_separator_is_refused(tmp_path):
    from encdesign.io._table import _column

    with pytest.raises(EncdesignInputError, match="line 3, column 'a'"):
        _column("t.csv", "a", ["1.0", "1_0"], [2, 3], "f")


# ----------------------------------------------------------------------------- issue 24, round 3


def _moteus_lines(n=12):
    return [f"1 {1300 * (i + 1)} {35332 + 40 * i}" for i in range(n)]


@pytest.mark.parametrize(
    ("bad", "col"),
    [("1 2600 1e300", "encoder"), ("3 2600 35372", "dir"), ("1 2.5 35372", "phase")],
)
def test_moteus_messages_name_the_file_line(tmp_path, bad, col):
    from encdesign.io._realdata import import_moteus

    body = _moteus_lines()
    body[4] = bad  # data row 4 sits on file line 8: a comment and two blank lines above it
    src = tmp_path / "m.txt"
    src.write_text("# dir phase encoder\n\n" + "\n".join(body[:2]) + "\n\n" + "\n".join(body[2:]))
    with pytest.raises(EncdesignInputError, match=f"line 8, column '{col}'"):
        import_moteus(src, tmp_path / "o.toml")
    assert not (tmp_path / "o.toml").exists()


def test_moteus_phase_jump_and_bad_cell_name_the_file_line(tmp_path):
    from encdesign.io._realdata import import_moteus

    body = _moteus_lines()
    body[6] = "1 40000 35600"
    src = tmp_path / "m.txt"
    src.write_text("# header\n" + "\n".join(body) + "\n")
    with pytest.raises(EncdesignInputError, match="line 8"):
        import_moteus(src, tmp_path / "o.toml")
    src.write_text("# header\n" + "\n".join(_moteus_lines()[:3]) + "\n1 1_0 3\n")
    with pytest.raises(EncdesignInputError, match="line 5"):
        import_moteus(src, tmp_path / "o.toml")


@pytest.mark.parametrize(
    ("key", "value", "named"),
    [
        ("upper", "1e300", "head_angles[0].upper"),
        ("upper", "[370.0, 1e300, 370.0]", "head_angles[1].upper"),
        ("lower", "[-10.0, -10.0, -1e300]", "head_angles[2].lower"),
        ("start", "[0.0, 1e300, 250.0]", "head_angles[1].start"),
        ("start", "[0.0, nan, 250.0]", "head_angles[1].start"),
        ("start", "[0.0, inf, 250.0]", "head_angles[1].start"),
    ],
)
def test_vector_variables_bounded_like_scalars(key, value, named):
    import tomllib
    from pathlib import Path

    from encdesign.design._problem import parse_problem

    text = (Path(__file__).parents[1] / "examples" / "head_layout_3.toml").read_text()
    lines = text.splitlines()
    i = lines.index("[variables.head_angles]")
    j = next(k for k in range(i, len(lines)) if lines[k].startswith(f"{key} ="))
    lines[j] = f"{key} = {value}"
    with pytest.raises(EncdesignInputError, match=re.escape(named)):
        parse_problem(tomllib.loads("\n".join(lines)), source="p.toml")


@pytest.mark.parametrize(
    ("table", "key"),
    [("constraints.yield_smooth", "lower"), ("yield", "spec"), ("driver", "rtol")],
)
@pytest.mark.parametrize("value", [1e300, -1e300])
def test_absurd_problem_numbers_refused(table, key, value):
    import tomllib
    from pathlib import Path

    from encdesign.design._problem import parse_problem

    raw = tomllib.loads(
        (Path(__file__).parents[1] / "examples" / "tolerance_cost_3p1.toml").read_text()
    )
    d = raw
    for k in table.split("."):
        d = d[k]
    d[key] = value
    with pytest.raises(EncdesignInputError, match=re.escape(f"{table}.{key}")):
        parse_problem(raw, source="p.toml")
