"""Property-based tests (hypothesis) over every command's flags and every reader (issue 24).

* Flags: every flag of every command, action and study that takes a value (a checked
  number, a choice, a string) is found in the parsers themselves, so a new flag is
  covered without a new line here; any text given to it is either parsed into its
  documented range (the bounds the checked type carries) or refused with exit 2 and one
  line; no numeric flag is a plain ``int`` / ``float``.
* Readers: the ``import`` readers (moteus, magalpha, servo, nmm, odrive), recordings of
  every kind (TOML and CSV cells, the closure and sds formats included) and case files,
  fed mutated versions of small valid files: each gives a result or an
  :class:`~encdesign.EncdesignInputError` naming the file, never another exception, and
  a refused import writes nothing. (Problem and design files: ``tests/test_fuzz.py``.)

Examples are derandomised and bounded; the module runs in well under a minute.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_cli_contract import REALDATA, STUDIES, study_parser_of

from encdesign._errors import EncdesignInputError
from encdesign.cli._main import OneLineParser, _command_modules, main
from encdesign.design._cases import read_cases, verify_case
from encdesign.io import _realdata
from encdesign.io._recording import load_recording

FUZZ = settings(
    max_examples=80,
    deadline=None,
    database=None,
    derandomize=True,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
        HealthCheck.function_scoped_fixture,
    ],
)

TEXT = st.one_of(
    st.integers(-(2**70), 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(
        ["nan", "inf", "-inf", "1e300", "-1e300", "-0", "0", "0x10", "1_000", "", " 3", "1e-300"]
    ),
    st.text(max_size=6),
)


# ----------------------------------------------------------------------------- flags


def _leaf_parsers(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    """``(action argv prefix, parser)`` of every leaf parser below ``parser``."""
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                yield from _leaf_parsers(sub, (*prefix, name))
            return
    yield prefix, parser


def _required(parser: argparse.ArgumentParser) -> list[str]:
    """Arguments that make a command line complete (dummy paths, first choices)."""
    out: list[str] = []
    for a in parser._actions:
        dummy = str(next(iter(a.choices))) if a.choices else "x.toml"
        if not a.option_strings:
            out.append(dummy)
        elif a.required:
            out += [a.option_strings[0], dummy]
    return out


def _flag_cases() -> list[tuple[str, object, list[str], argparse.Action]]:
    """``(label, parser, argv before the flag, action)`` of every value-taking flag."""
    cases = []
    parsers = []
    for name, modname in _command_modules().items():
        p = OneLineParser(prog=f"encdesign {name}")
        importlib.import_module(modname).configure(p)
        parsers += [(" ".join((name, *pre)), leaf, list(pre)) for pre, leaf in _leaf_parsers(p)]
    with pytest.MonkeyPatch.context() as mp:
        parsers += [(f"study run {s}", study_parser_of(s, mp), []) for s in STUDIES]
    for label, leaf, pre in parsers:
        for a in leaf._actions:
            if a.option_strings and a.nargs != 0 and a.type is not Path and a.dest != "help":
                cases.append((f"{label} {a.option_strings[0]}", leaf, pre + _required(leaf), a))
    return cases


FLAG_CASES = _flag_cases()


def test_every_numeric_flag_has_a_checked_type():
    plain = [label for label, _, _, a in FLAG_CASES if a.type in (int, float)]
    assert not plain, plain
    assert len(FLAG_CASES) > 80  # the commands and studies together


def _check_value(v, a: argparse.Action) -> None:
    if a.choices:
        assert v in a.choices
    if isinstance(v, bool) or not isinstance(v, int | float):
        return
    assert math.isfinite(v)
    lo, hi = vars(a.type).get("bounds", (None, None)) if a.type is not None else (None, None)
    assert lo is None or lo <= v, (v, lo)
    assert hi is None or v <= hi, (v, hi)


@FUZZ
@given(st.sampled_from(range(len(FLAG_CASES))), TEXT)
def test_every_flag_parses_into_its_range_or_refuses_in_one_line(tmp_path, i, text):
    label, parser, before, action = FLAG_CASES[i]
    flag = action.option_strings[0]
    argv = [*before, f"{flag}={text}"]
    if label.startswith("study"):  # the study's output folder, checked when parsed
        argv += ["--out", str(tmp_path / "o")]
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            ns = parser.parse_args(argv)  # type: ignore[attr-defined]
        except SystemExit as exc:
            assert exc.code == 2, (label, text)
            lines = err.getvalue().strip().splitlines()
            assert len(lines) == 1 and "Traceback" not in lines[0], err.getvalue()
            return
    value = getattr(ns, action.dest)
    for v in value if isinstance(value, list) else [value]:
        _check_value(v, action)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("i", range(0, len(FLAG_CASES)), ids=lambda i: FLAG_CASES[i][0])
def test_every_flag_refuses_absurd_values(tmp_path, i):
    """1e300, NaN and a Python literal never come back as a value out of range."""
    label, parser, before, action = FLAG_CASES[i]
    for text in ("1e300", "nan", "1_0", "-1e300"):
        argv = [*before, f"{action.option_strings[0]}={text}"]
        if label.startswith("study"):
            argv += ["--out", str(tmp_path / "o")]
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            try:
                ns = parser.parse_args(argv)  # type: ignore[attr-defined]
            except SystemExit as exc:
                assert exc.code == 2
                continue
        value = getattr(ns, action.dest)
        for v in value if isinstance(value, list) else [value]:
            _check_value(v, action)


# ----------------------------------------------------------------------------- readers

ODD_TOKENS = st.one_of(
    st.sampled_from(
        ["1e300", "-1e300", "nan", "inf", "-inf", "1_0", "0x10", "", "x", "1e20", "-1", "2.5"]
        + ["65536", "9" * 30, "\x00", "\ufeff1", "1,2", "# c", "1 2", "\t"]
    ),
    st.integers(-(2**70), 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(max_size=5),
)

SOURCES = {
    "moteus": ("moteus_encoder_cal.txt", 40, " "),
    "magalpha": ("magalpha_calibration_example.csv", 40, ","),
    "servo": ("servo_optical_encoder_capture.txt", 60, " "),
    "nmm": ("nmm_X_raw.csv", 40, ","),
}


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz-cmd")


@FUZZ
@given(st.sampled_from(sorted(SOURCES)), st.data(), ODD_TOKENS)
def test_import_text_readers_read_or_refuse(scratch, kind, data, token):
    name, n, sep = SOURCES[kind]
    lines = (REALDATA / name).read_text().splitlines()[:n]
    how = data.draw(st.sampled_from(["cell", "line", "insert", "truncate", "bytes"]))
    i = data.draw(st.integers(0, n - 1))
    if how == "cell":
        cells = lines[i].split(sep)
        cells[data.draw(st.integers(0, len(cells) - 1))] = token
        lines[i] = sep.join(cells)
    elif how == "line":
        lines[i] = token
    elif how == "insert":
        lines.insert(i, token)
    elif how == "truncate":
        lines = lines[:i]
    blob = ("\n".join(lines) + "\n").encode("utf-8", "surrogatepass")
    if how == "bytes":
        blob = blob[: data.draw(st.integers(0, len(blob)))] + data.draw(st.binary(max_size=40))
    src, out = scratch / f"src_{kind}.txt", scratch / f"{kind}" / "o.toml"
    shutil.rmtree(out.parent, ignore_errors=True)
    src.write_bytes(blob)
    try:
        rec = getattr(_realdata, f"import_{kind}")(src, out)
    except EncdesignInputError as exc:
        msg = str(exc)
        assert str(src) in msg and "\n" not in msg, msg
        assert not out.exists()
    else:
        assert rec.n_rows >= 3
        for col in rec.columns.values():
            assert np.all(np.isfinite(col))


@FUZZ
@given(
    st.sampled_from(["shape", "value", "dtype", "bytes"]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(0, 3),
)
def test_odrive_reader_reads_or_refuses(scratch, how, value, k):
    a = np.load(REALDATA / "odrive_slow2_comp_0.npy")[:, :300].copy()
    src = scratch / "o.npy"
    if how == "shape":
        a = a[: k + 1] if k < 3 else a.T
    elif how == "value":
        a[min(k, 2), 7] = value
    elif how == "dtype":
        a = a.astype([np.float32, np.int64, np.complex128, np.float16][k])
    np.save(src, a)
    if how == "bytes":
        src.write_bytes(src.read_bytes()[: 64 + 97 * k])
    try:
        _realdata.read_odrive_npy(src)
    except EncdesignInputError as exc:
        assert str(src) in str(exc)


@pytest.fixture(scope="module")
def recordings(scratch) -> dict[str, Path]:
    """One small recording of each kind the commands write (multihead, sds, closure,
    quadrature)."""
    from test_cli_contract import _closure
    from test_guard import DESIGN

    d = scratch / "recs"
    d.mkdir()
    (d / "design.toml").write_text(DESIGN)
    quiet = contextlib.redirect_stdout(io.StringIO())
    with quiet:
        assert main(["simulate", str(d / "design.toml"), "--out", str(d / "mh.toml")]) == 0
        sds = ["sds", "simulate", "--out", str(d / "sds.toml"), "--marks", "40", "--revs", "1"]
        assert main([*sds, "--phi-deg", "0"]) == 0
        assert main(["conceal", str(d / "q.toml"), "--samples-per-run", "64"]) == 0
    _closure(d / "cl.toml")
    return {k: d / f"{k}.toml" for k in ("mh", "sds", "q", "cl")}


@FUZZ
@given(st.sampled_from(["mh", "sds", "q", "cl"]), st.data(), ODD_TOKENS)
def test_recording_cells_and_keys_read_or_refuse(scratch, recordings, kind, data, token):
    src = recordings[kind]
    d = scratch / f"m_{kind}"
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir()
    toml = src.read_text()
    table = src.with_suffix(".csv").read_text().splitlines()[:40]
    if data.draw(st.booleans()):
        i = data.draw(st.integers(0, len(table) - 1))
        cells = table[i].split(",")
        cells[data.draw(st.integers(0, len(cells) - 1))] = token
        table[i] = ",".join(cells)
    else:
        lines = toml.splitlines()
        eq = [j for j, ln in enumerate(lines) if " = " in ln]
        j = data.draw(st.sampled_from(eq))
        lines[j] = (
            lines[j].split(" = ")[0]
            + " = "
            + data.draw(
                st.sampled_from([token, repr(token), f"[{token}]", "1e300", "-1", "[]", "{}"])
            )
        )
        toml = "\n".join(lines) + "\n"
    (d / src.name).write_text(toml, encoding="utf-8", errors="surrogatepass")
    (d / src.with_suffix(".csv").name).write_text(
        "\n".join(table) + "\n", encoding="utf-8", errors="surrogatepass"
    )
    try:
        rec = load_recording(d / src.name)
    except EncdesignInputError as exc:
        assert str(d) in str(exc) and "\n" not in str(exc), str(exc)
    else:
        for col in rec.columns.values():
            if np.issubdtype(col.dtype, np.number):
                assert np.all(np.abs(col) <= 1e16)


@FUZZ
@given(st.sampled_from([".jsonl", ".csv"]), st.data(), ODD_TOKENS)
def test_case_files_read_or_refuse(scratch, suffix, data, token):
    from encdesign.design._cases import Case, write_cases

    p = scratch / f"cases{suffix}"
    write_cases(p, [Case(i, {"x": 0.1 * i}, {"f": float(i)}, "success", 1) for i in range(4)])
    lines = p.read_text().splitlines()
    i = data.draw(st.integers(0, len(lines) - 1))
    if data.draw(st.booleans()):
        lines[i] = token
    else:
        j = data.draw(st.integers(0, max(0, len(lines[i]) - 1)))
        lines[i] = lines[i][:j] + token + lines[i][j:]
    p.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogatepass")
    try:
        for c in read_cases(p):
            verify_case(c, p)
    except EncdesignInputError as exc:
        assert str(p) in str(exc), str(exc)
