"""The README's sensitivity paragraph quotes benchmarks/finder_sensitivity.json by field: every
number and list it gives must be the JSON's."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
JSON = ROOT / "benchmarks" / "finder_sensitivity.json"


def paragraph(readme: str) -> str:
    """The README paragraph (blank-line separated) that names the sweep's JSON, on one line."""
    paras = [p for p in readme.split("\n\n") if "benchmarks/finder_sensitivity.json" in p]
    assert len(paras) == 1, f"{len(paras)} README paragraphs name the sweep's JSON"
    return " ".join(paras[0].split())


def quoted_names(text: str, field: str) -> tuple[int, set[str]]:
    """``(count, names)`` of a clause ```field` (K): `a`, `b``` (or ``none``)."""
    m = re.search(rf"`{field}` \((\d+)\): ((?:none|`[a-z0-9_]+`(?:, `[a-z0-9_]+`)*))", text)
    assert m, f"the paragraph does not quote `{field}` (K): names"
    return int(m.group(1)), set(re.findall(r"`([a-z0-9_]+)`", m.group(2)))


def check(text: str, d: dict) -> None:
    """Raise AssertionError where ``text`` misquotes the sweep ``d``."""
    n = len(d["recordings"])
    m = re.search(r"`default_right` = (\d+) of (\d+)", text)
    assert m and (int(m.group(1)), int(m.group(2))) == (d["default_right"], n), m
    m = re.search(r"`thresholds_done`: (\d+) of `fields_total` (\d+)", text)
    assert m and (int(m.group(1)), int(m.group(2))) == (
        len(d["thresholds_done"]),
        d["fields_total"],
    ), m
    m = re.search(r"`complete`: (true|false)", text)
    assert m and (m.group(1) == "true") == d["complete"], m
    for field in ("rate_drops", "rate_rises", "over"):
        k, names = quoted_names(text, field)
        assert (k, names) == (len(d[field]), set(d[field])), (field, k, names, d[field])
    rows = {(r["threshold"], float(r["factor"])): r for r in d["rows"]}
    per_row = re.findall(r"`([a-z0-9_]+)` x(\d+(?:\.\d+)?): (\d+)/(\d+)", text)
    assert per_row or not d["rate_drops"], "the drops are not quoted per factor"
    for name, fac, right, of in per_row:
        r = rows.get((name, float(fac)))
        assert r is not None, f"{name} x{fac} is not in the JSON"
        assert (int(right), int(of)) == (r["right"], n), (name, fac, right, r["right"])
    m = re.search(r"`largest_drop` (-?\d+(?:\.\d+)?)", text)
    assert m and abs(float(m.group(1)) - d["largest_drop"]) < 5e-4, m


def test_readme_quotes_the_sweep_by_field():
    d = json.loads(JSON.read_text(encoding="utf-8"))
    check(paragraph((ROOT / "README.md").read_text(encoding="utf-8")), d)


def test_the_json_is_a_labelled_sweep_with_sds():
    d = json.loads(JSON.read_text(encoding="utf-8"))
    assert "sds" in d["kinds"] and any(k.startswith("sds/") for k in d["recordings"])
    assert set(d["truth"]) == set(d["recordings"])
    for r in d["rows"]:
        if r.get("invalid"):  # a moved value the settings refuse: nothing diagnosed
            assert r["right"] is None and r["delta_rate"] == 0.0
            continue
        assert r["delta_right"] == r["right"] - d["default_right"]


def test_a_misquote_is_caught():
    d = json.loads(JSON.read_text(encoding="utf-8"))
    text = paragraph((ROOT / "README.md").read_text(encoding="utf-8"))
    wrong = text.replace(
        f"`default_right` = {d['default_right']}", f"`default_right` = {d['default_right'] + 1}"
    )
    with pytest.raises(AssertionError):
        check(wrong, d)
    bad = dict(d, rate_drops=[*d["rate_drops"], "not_a_field"])
    with pytest.raises(AssertionError):
        check(text, bad)
