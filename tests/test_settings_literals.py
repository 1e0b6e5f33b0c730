"""Every decision number of the finder is a :class:`FinderSettings` field (issue 44 G, item 2).

An AST scan of every module under ``encdesign/diagnose/`` collects the numeric literals inside
comparisons (the operands of every ``ast.Compare``, including literals inside arithmetic and
calls there, as in ``x > 0.25 * y``); a literal that is not allow-listed here with a reason
fails the test. Literals in a subscript's index (``x[:, 0] > thr``) are indices and are not
collected. The allow-list holds numerical constants, counts, array shapes, physics and
plotting numbers only: a threshold that decides what the finder reports belongs in
``FinderSettings`` (documented, in the generated table of ``docs/diagnose.md``), not here.

``min`` / ``max`` / ``np.clip`` arguments are not scanned: what is there is guards
(``max(x, 1e-300)``), block and window sizes and caps on a model's order (see the module
constants ``CHUNK_ROWS`` etc.), not comparisons.
"""

from __future__ import annotations

import ast
from pathlib import Path

DIAGNOSE = Path(__file__).resolve().parent.parent / "encdesign" / "diagnose"

# ---- reasons (one category each) -------------------------------------------------------
SIGN = "0 / 1 / -1: a sign, emptiness, unit or direction test (not a tuned number)"
GUARD = "numerical guard: keeps a division or a log finite (float64 underflow)"
NUMERIC = "numerical tolerance: float64 rounding, a solver's convergence or a rank cut-off"
COUNT = "count: the least rows / values / runs / channels an estimator or a test needs"
DOF = "count: degrees of freedom or columns of a term (2 = a cos / sin pair)"
SHAPE = "array shape, parity or a one-hot / integer index rounded at 0.5"
PHYSICS = "physics or geometry (2 pi, the harmonic 2L, the runout orders 1-3)"
SEARCH = "search: where an optimiser starts or how fine its grid is, not what it accepts"
REPORT = "report: how many alternatives or partners are listed, not a verdict"
PLOT = "plot layout only"

UNIVERSAL = {0: SIGN, 1: SIGN, -1: SIGN, 1e-300: GUARD}
"""Allowed in every module."""

ALLOWED: dict[tuple[str, float], str] = {
    # engine
    ("engine/_discover.py", -2): SHAPE + " (the sentinel line index of the run constants)",
    ("engine/_discover.py", 2): DOF + " (two cos / sin columns of one channel)",
    ("engine/_discover.py", 1e-6): NUMERIC + " (two line values equal to rounding)",
    ("engine/_discover.py", 1e-12): GUARD + " (log of a speed)",
    ("engine/_engine.py", 2): PHYSICS,
    ("engine/_evidence.py", 2): REPORT + " (at most two confounded partners)",
    ("engine/_evidence.py", 3): REPORT + " (at most three alternatives)",
    ("engine/_fit.py", 1e-200): NUMERIC + " (a zero diagonal of the normal matrix)",
    ("engine/_fit.py", 1e-10): NUMERIC + " (a Jacobian column lost in rounding)",
    ("engine/_fit.py", 1e-7): NUMERIC + " (Levenberg-Marquardt convergence)",
    ("engine/_fit.py", 1e-2): NUMERIC + " (LM convergence: 0.01 of chi-square)",
    ("engine/_fit.py", 1e8): NUMERIC + " (LM damping gives up)",
    ("engine/_fit.py", 16): COUNT + " (a block of the goodness-of-fit test)",
    ("engine/_html.py", 2): SHAPE,
    ("engine/_html.py", 6): PLOT,
    ("engine/_html_discovery.py", 3): PLOT,
    ("engine/_html_discovery.py", 100): PLOT,
    ("engine/_lattice.py", 2): COUNT,
    ("engine/_noise.py", 3): COUNT,
    ("engine/_noise.py", 4): COUNT,
    ("engine/_noise.py", 8): COUNT,
    ("engine/_noise.py", 16): COUNT,
    ("engine/_nuisances.py", 2): COUNT + "; 2 pi",
    ("engine/_prepare.py", 2): COUNT + "; half a window; two channels of a quadrature pair",
    ("engine/_prepare.py", 3): COUNT + "; 3.0 in the sum of squares h(h+1)(2h+1)/3",
    ("engine/_prepare.py", 8): COUNT,
    ("engine/_prepare.py", 16): COUNT,
    ("engine/_results.py", 2): SHAPE + " (a pair)",
    ("engine/_results.py", 1e-12): NUMERIC + " (a correlation <= 1 up to rounding)",
    ("engine/_select.py", 2): SHAPE + " (a squared correlation)",
    ("engine/_settings.py", 2): COUNT + " (K-fold needs 2 folds)",
    ("engine/_stepped.py", 8): COUNT + " (the segment finder's own minimum)",
    ("engine/_steps.py", 2): COUNT,
    ("engine/_steps.py", 48): SEARCH + " (rows tried in a step's fine search)",
    ("engine/_views.py", 2): COUNT + "; DOF; parity of a run length",
    ("engine/_views.py", 4): COUNT + " (bins of a band)",
    ("engine/_views.py", 1e-9): NUMERIC,
    ("engine/_views.py", 1e-12): NUMERIC + " (nothing left after the run constants); guard",
    # kinds
    ("kinds/multihead/_multihead.py", 2): COUNT + " (two heads or runs); 2 pi",
    ("kinds/multihead/_multihead.py", 4): COUNT,
    ("kinds/multihead/_multihead.py", 1e-12): NUMERIC + " (a step at its own row)",
    ("kinds/multihead/_multihead_terms.py", 2): PHYSICS + "; DOF; a squared trace",
    ("kinds/multihead/_multihead_terms.py", 3): PHYSICS,
    ("kinds/multihead/_multihead_terms.py", 1e-6): NUMERIC + " (a zero pattern vector)",
    ("kinds/multihead/_multihead_terms.py", 1e-9): NUMERIC + " (a singular 2x2 matrix)",
    ("kinds/multihead/_reference_data.py", 2): COUNT,
    ("kinds/multihead/_reference_terms.py", 2): SHAPE,
    ("kinds/multihead/_reference_terms.py", 8): COUNT,
    ("kinds/multihead/_reference_terms.py", 0.5): SHAPE,
    ("kinds/quadrature/_quadrature.py", 2): SHAPE + " (the two coordinates of the centre)",
    ("kinds/quadrature/_quadrature.py", 4): SHAPE + " (an order's parity mod 4)",
    ("kinds/quadrature/_quadrature.py", 16): COUNT,
    ("kinds/quadrature/_quadrature.py", 32): COUNT + " (samples for a conic fit)",
    ("kinds/sds/_sds_data.py", 2): COUNT + " (revolutions per run); two mark periods",
    ("kinds/sds/_sds_data.py", 4): COUNT + " (runs, marks)",
    ("kinds/sds/_sds_data.py", 16): COUNT + " (stamp differences)",
    ("kinds/sds/_sds_noise.py", 2): COUNT + "; DOF; a squared norm",
    ("kinds/sds/_sds_noise.py", 3): COUNT + " (degrees of freedom of an F-test)",
    ("kinds/sds/_sds_noise.py", 1e-9): NUMERIC,
    ("kinds/sds/_sds_noise.py", 1e-10): NUMERIC + " (rank cut-off)",
    ("kinds/sds/_sds_noise.py", 1e4): NUMERIC + " (F tends to chi-square: no widening)",
    ("kinds/sds/_sds_terms.py", 2): COUNT + " (two sensors)",
    ("kinds/sds/_sds_terms.py", 3): SEARCH + " (three starts)",
    ("kinds/sds/_sds_terms.py", 0.03): SEARCH + " (distinct start ratios)",
    ("kinds/sds/_sds_terms.py", 0.5): SHAPE,
    ("kinds/sds/_sds_terms.py", 1e-9): NUMERIC,
}
"""``(module under encdesign/diagnose, literal) -> reason``; every entry must be used."""


def _number(node: ast.AST) -> float | None:
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        return node.value
    if (
        isinstance(node, ast.UnaryOp)
        and isinstance(node.op, ast.USub)
        and isinstance(node.operand, ast.Constant)
        and type(node.operand.value) in (int, float)
    ):
        return -node.operand.value
    return None


def _literals(node: ast.AST):
    """Numeric literals in an operand, arithmetic and calls included, indices excluded."""
    v = _number(node)
    if v is not None:
        yield node, v
        return
    if isinstance(node, ast.Subscript):
        yield from _literals(node.value)
        return
    for child in ast.iter_child_nodes(node):
        yield from _literals(child)


def compared_literals(source: str) -> list[tuple[int, float, str]]:
    """``(line, literal, line text)`` of every numeric literal inside a comparison."""
    lines = source.splitlines()
    out, seen = [], set()
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Compare):
            continue
        for operand in (node.left, *node.comparators):
            for lit, v in _literals(operand):
                if (lit.lineno, lit.col_offset) not in seen:
                    seen.add((lit.lineno, lit.col_offset))
                    out.append((lit.lineno, v, lines[lit.lineno - 1].strip()))
    return sorted(out)


def scan(root: Path = DIAGNOSE) -> tuple[list[str], set[tuple[str, float]]]:
    """Literals not allow-listed (``module:line: literal: text``) and the entries used."""
    bad, used = [], set()
    for path in sorted(root.rglob("*.py")):
        mod = path.relative_to(root).as_posix()
        for line, v, text in compared_literals(path.read_text(encoding="utf-8")):
            if v in UNIVERSAL:
                continue
            if (mod, v) in ALLOWED:
                used.add((mod, v))
                continue
            bad.append(f"{mod}:{line}: {v!r}: {text}")
    return bad, used


def test_every_decision_number_in_the_diagnose_modules_is_a_setting():
    bad, _ = scan()
    assert not bad, (
        "numeric literals in comparisons under encdesign/diagnose/ that are neither a "
        "FinderSettings field nor allow-listed in tests/test_settings_literals.py (a "
        "threshold that decides a finding: move it into FinderSettings with its docstring "
        "and regenerate docs/diagnose.md's table; a numerical constant or a count: "
        "allow-list it with its reason):\n" + "\n".join(bad)
    )


def test_the_allow_list_has_no_stale_entry():
    _, used = scan()
    stale = sorted(set(ALLOWED) - used)
    assert not stale, f"allow-listed literals no longer found (remove them): {stale}"
    assert all(reason.strip() for reason in ALLOWED.values())


def test_the_scan_finds_a_threshold_inside_arithmetic(tmp_path):
    """The scan can fail: a threshold in arithmetic, a chained comparison and a call in a
    comparison are found; an index, a string and a number outside a comparison are not."""
    src = (
        "def f(pw, x, k):\n"
        "    a = 0.7 * x\n"
        "    if pw[k] >= 0.25 * pw.max():\n"
        "        return x[:, 3] > a\n"
        "    return -0.5 < g(x, 2.5) <= 'a'\n"
    )
    found = [(line, v) for line, v, _ in compared_literals(src)]
    assert found == [(3, 0.25), (5, -0.5), (5, 2.5)]
    pkg = tmp_path / "engine"
    pkg.mkdir()
    (pkg / "_views.py").write_text(src, encoding="utf-8")
    bad, _ = scan(tmp_path)
    assert len(bad) == 3 and bad[0].startswith("engine/_views.py:3: 0.25:")
