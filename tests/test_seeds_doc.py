"""benchmarks/SEEDS.md (the seeds used while building) and the README's rates on fresh seeds.

A rate is reported on seeds outside the list. The README writes such a rate as "on fresh seeds
S, ..."; those seeds must be listed in SEEDS.md's last table (the fresh sets that measured
rates) and in none of the tables above it (the training seeds)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FRESH_HEADING = "## Fresh seeds that measured rates"
FRESH_RE = re.compile(
    r"fresh seeds? ((?:\d+(?:\s*-\s*\d+)?)(?:(?:,\s*|\s+and\s+)\d+(?:\s*-\s*\d+)?)*)"
)


def seeds_in(text: str) -> set[int]:
    """The seeds of one cell or phrase: numbers and ranges ``a-b``; parentheses are
    comments (innermost first, so nested ones go too)."""
    while True:
        stripped = re.sub(r"\([^()]*\)", " ", text)
        if stripped == text:
            break
        text = stripped
    out: set[int] = set()
    for a, b in re.findall(r"(\d+)(?:\s*-\s*(\d+))?", text):
        lo, hi = int(a), int(b) if b else int(a)
        if hi < lo or hi - lo > 10_000:
            raise ValueError(f"not a seed range: {a}-{b}")
        out.update(range(lo, hi + 1))
    return out


def table_seeds(markdown: str) -> set[int]:
    """The seeds of every table row's last column (header and separator rows skipped)."""
    out: set[int] = set()
    rows = [ln for ln in markdown.splitlines() if ln.startswith("|")]
    for ln in rows:
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        if set(ln) <= set("|- ") or cells[-1] in ("seeds", "seeds used while building"):
            continue
        out |= seeds_in(cells[-1].replace("\\|", "/"))
    return out


@pytest.fixture(scope="module")
def lists() -> tuple[set[int], set[int]]:
    text = (ROOT / "benchmarks" / "SEEDS.md").read_text(encoding="utf-8")
    assert FRESH_HEADING in text, "SEEDS.md lost its table of fresh sets"
    training, fresh = text.split(FRESH_HEADING)
    return table_seeds(training), table_seeds(fresh)


def test_the_list_holds_the_seeds_known_to_be_used(lists):
    training, _ = lists
    # failures fixed on them, benchmarks built on them, the issue 44 tests
    for s in (0, 1, 2, 83, 84, 85, 86, 71, 72, 73, 31, 35, 41, 43, 20261204, 20261205):
        assert s in training, s


def test_fresh_sets_were_not_training_seeds(lists):
    training, fresh = lists
    assert fresh, "no fresh set listed"
    assert not fresh & training, sorted(fresh & training)


def test_readme_rates_on_fresh_seeds_use_listed_fresh_seeds(lists):
    training, fresh = lists
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    quoted = [m.group(1) for m in FRESH_RE.finditer(" ".join(readme.split()))]
    assert quoted, "the README quotes no rate on fresh seeds"
    for q in quoted:
        got = seeds_in(q)
        assert got <= fresh, f"README 'fresh seeds {q}': {sorted(got - fresh)} not in SEEDS.md"
        assert not got & training, f"README 'fresh seeds {q}': training seeds {got & training}"


def test_the_checks_can_fail():
    training = table_seeds("| a | b |\n| --- | --- |\n| x | 83-85 (on 4,000 rows); 7 |\n")
    assert training == {83, 84, 85, 7}
    assert seeds_in("1301, 1302 (session 14 (two))") == {1301, 1302}
    m = FRESH_RE.search("variations on fresh seeds 83-84 and 90: 8/8")
    assert m is not None and seeds_in(m.group(1)) & training == {83, 84}
