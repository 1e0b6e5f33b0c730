"""docs/seeds.md's rows: one machine-readable source, every label checked against its numbers."""

import copy
import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(name):
    path = ROOT / "studies" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{name}_under_test", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def st():
    return _load("seeds_table")


@pytest.fixture(scope="module")
def data(st):
    return st.load()


def test_every_label_matches_its_numbers(st, data):
    problems = [b for r in data["rows"] for b in st.check_row(r)]
    assert not problems, "\n".join(problems)
    ids = [r["id"] for r in data["rows"]]
    assert len(ids) == len(set(ids)) == 107


def test_every_calibration_row_carries_its_numbers(st, data):
    """Each row that quotes the seed-calibration study holds a check with the model value,
    its uncertainty and the seed's value or bound; predictions come from 'predict' figures."""
    for r in data["rows"]:
        if "[cal" in r["encdesign"] and r["label"] not in ("not simulated",):
            c = r.get("check")
            assert c is not None, f"row {r['id']} quotes [cal] without a check"
            assert {"model", "model_sd", "seed"} <= set(c), r["id"]
            assert (c.get("bound") == "upper") != ("seed_sigma" in c), r["id"]
            if r["label"] in ("agrees", "disagrees"):
                assert c.get("kind") == "predict", r["id"]


def test_the_doc_is_the_rendering(st, data):
    text = st.DOC_PATH.read_text(encoding="utf-8")
    assert st.render_doc(text, data) == text, "run: encdesign study run seeds-table --write-doc"
    for r in data["rows"]:  # no cell breaks the markdown table
        for k in ("result", "seed_value", "encdesign", "reason"):
            assert "|" not in r.get(k, ""), (r["id"], k)


def test_the_label_check_fails_on_the_rows_before_issue_42(st, data):
    """Rows 1.32 and 1.57 as they read before issue 42: 1.32 'agrees' at 38.8 ± 3.1 mas
    against the seed's 'did not exceed 32 mas' (then encoded as 32 ± 3.2), 1.57 'agrees' at
    z +2.3. Both contradict the rule; so does a bound that carries a Gaussian σ."""
    old_132 = {
        "id": "1.32",
        "label": "agrees",
        "check": {
            "model": 38.8,
            "model_sd": 3.1,
            "seed": 32.0,
            "bound": "upper",
            "kind": "predict",
        },
    }
    assert any("bound is exceeded" in b for b in st.check_row(old_132))
    as_gaussian = copy.deepcopy(old_132)
    as_gaussian["check"]["seed_sigma"] = 3.2
    assert any("not a Gaussian" in b for b in st.check_row(as_gaussian))
    old_157 = {
        "id": "1.57",
        "label": "agrees",
        "check": {
            "model": 0.122,
            "model_sd": 0.013,
            "seed": 0.05,
            "seed_sigma": 0.03,
            "kind": "hypothesis",
        },
    }
    bad = st.check_row(old_157)
    assert any("z +2.2" in b for b in bad) and any("not a prediction" in b for b in bad)
    # and today's rows pass
    today = {r["id"]: r for r in data["rows"]}
    assert not st.check_row(today["1.32"]) and not st.check_row(today["1.57"])


def test_label_check_catches_each_kind_of_mismatch(st):
    ok = {
        "id": "9.1",
        "label": "agrees",
        "check": {
            "model": 1.0,
            "model_sd": 0.1,
            "seed": 1.1,
            "seed_sigma": 0.1,
            "kind": "predict",
            "source": "cal:x/y",
        },
    }
    assert st.check_row(ok) == []
    wrong = dict(ok, label="disagrees", reason="x")
    assert st.check_row(wrong)
    fitted_pred = dict(ok, label="fitted")
    assert st.check_row(fitted_pred)
    bare = {"id": "9.2", "label": "agrees"}
    assert st.check_row(bare)
    apart = {"id": "9.3", "label": "constant", "verdict": "disagrees", "check": ok["check"]}
    assert st.check_row(apart)
    assert st.check_row({"id": "9.4", "label": "explained"})
    assert st.check_row({"id": "9.5", "label": "disagrees", "check": {**ok["check"], "seed": 3.0}})


def test_agreement_is_the_calibration_studys_rule(st):
    sc = _load("seed_calibration")
    rng = np.random.default_rng(42)
    for _ in range(200):
        m, sd, s, sg = rng.normal(0, 2), abs(rng.normal(0, 1)), rng.normal(0, 2), abs(rng.normal())
        for bound in (None, "upper"):
            assert (
                st.agreement(m, sd, s, sg, bound)["agrees"]
                == sc.agreement(m, sd, s, sg, bound)["agrees"]
            )


def test_numbers_come_from_a_calibration_json(st, data):
    d = copy.deepcopy(data)
    every = [c for r in d["rows"] for c in st.checks(r)]
    closed = {c["source"][3:]: c["model"] for c in every if c["source"].startswith("cf:")}
    assert len(closed) >= 14
    cal = {
        "closed_forms": closed,
        "predicted_within_2sigma": 1,
        "predicted_total": 2,
        "instruments": [
            {
                "instrument": "seed002-shaker",
                "figures": [
                    {"key": "area_worst", "model": 0.52, "model_sd": 0.01, "kind": "predict"}
                ],
            }
        ],
    }
    with pytest.raises(ValueError, match="not in the calibration JSON"):
        st.update_from_calibration(d, cal)
    figs = {
        c["source"][4:]: dict(
            key=c["source"].split("/")[1],
            model=c["model"],
            model_sd=c["model_sd"],
            kind=c["kind"],
        )
        for c in every
        if c["source"].startswith("cal:")
    }
    figs["seed002-shaker/area_worst"]["model"] = 0.52
    insts = {}
    for k, v in figs.items():
        insts.setdefault(k.split("/")[0], []).append(v)
    cal["instruments"] = [{"instrument": k, "figures": v} for k, v in insts.items()]
    st.update_from_calibration(d, cal)
    row = next(r for r in d["rows"] if r["id"] == "2.19")
    assert row["check"]["model"] == 0.52
    assert any("numbers say" in b for b in st.check_row(row))  # 'disagrees' no longer holds
    assert d["calibration"] == {"predicted_within_2sigma": 1, "predicted_total": 2}
    # the seed's arithmetic comes from the study's closed forms: a misprint would show
    closed["s002_2mm_s_hz"] = 104.0
    st.update_from_calibration(d, cal)
    row = next(r for r in d["rows"] if r["id"] == "2.11")
    assert any("verdict" in b for b in st.check_row(row))


def test_readme_and_doc_quote_the_count_of_genuine_predictions(data):
    n, m = data["calibration"]["predicted_within_2sigma"], data["calibration"]["predicted_total"]
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    doc = (ROOT / "docs" / "seeds.md").read_text(encoding="utf-8")
    want = f"{n} of {m}"
    assert re.search(rf"genuine predictions[^.]*\*\*{want}", readme, re.I | re.S), want
    assert f"**Genuine predictions within 2σ: {want}**" in doc


GENERIC = (
    "no number to compare with a σ: the seed's claim is exact, a curve or a statement; "
    "the row names the test or key"
)


def test_every_verdict_carries_its_numbers_or_says_why_not(st, data):
    """A prediction or an arithmetic row carries its numbers, each with its source; an
    'agrees' without numbers is allowed only when the seed has no number, said so with the
    reason (the generic flag of before is refused)."""
    n_numbers = n_qualitative = 0
    for r in data["rows"]:
        cs = st.checks(r)
        if r["label"] in st.PREDICTION_LABELS + st.APART_LABELS:
            if cs:
                n_numbers += 1
                for c in cs:
                    assert {"model", "model_sd", "seed", "source"} <= set(c), r["id"]
                    assert (c.get("bound") in ("upper", "lower")) != ("seed_sigma" in c), r["id"]
            else:
                assert r["label"] == "agrees", r["id"]
                assert r["qualitative"].startswith(st.QUALITATIVE_PREFIX), r["id"]
                n_qualitative += 1
    assert n_numbers >= 37 and n_qualitative <= 18, (n_numbers, n_qualitative)
    row = {"id": "9.6", "label": "agrees", "qualitative": GENERIC}
    assert any("expected" in b for b in st.check_row(row))
    row["qualitative"] = st.QUALITATIVE_PREFIX
    assert any("expected" in b for b in st.check_row(row))
    row["qualitative"] = st.QUALITATIVE_PREFIX + "a curve without a quoted value"
    assert st.check_row(row) == []
    with_numbers = dict(row, check={"model": 1, "seed": 2, "bound": "upper", "source": "cf:x"})
    assert any("carries numbers" in b for b in st.check_row(with_numbers))
    no_source = {"id": "9.7", "label": "agrees", "check": {"model": 1, "seed": 2, "bound": "upper"}}
    assert any("source" in b for b in st.check_row(no_source))
    bare_arith = {"id": "9.8", "label": "arithmetic", "verdict": "agrees"}
    assert st.check_row(bare_arith)
    assert st.check_row({"id": "9.9", "label": "arithmetic"})


def test_lower_bounds_and_lists_of_numbers(st, data):
    """'slightly more than 0.2 arcsec' is a lower bound: 0.206 meets it, 0.19 does not, and
    a bound never carries the seed's σ; a row of counts agrees only when every count does."""
    rows = {r["id"]: copy.deepcopy(r) for r in data["rows"]}
    r = rows["1.62"]
    assert r["check"]["bound"] == "lower" and st.check_row(r) == []
    r["check"]["model"] = 0.19
    assert any("verdict" in b for b in st.check_row(r))
    r["check"]["model_sd"] = 0.01  # within 2σ_model of the bound: met
    assert st.check_row(r) == []
    r["check"]["seed_sigma"] = 0.05
    assert any("not a Gaussian" in b for b in st.check_row(r))
    counts = rows["1.40"]
    assert [c["seed"] for c in counts["check"]] == [156, 146, 24]
    assert st.check_row(counts) == []
    counts["check"][2]["model"] = 25.0  # one count off: the row no longer agrees
    assert any("verdict" in b for b in st.check_row(counts))
    assert "25" in st._cell(counts)  # the cell quotes the numbers it is checked on


def test_closed_form_numbers_are_the_studys(st, data):
    """Every 'cf:' number in the table is what seed-calibration's closed forms compute now
    (a dotted source reaches into a nested entry: the closure counts)."""
    closed = _load("seed_calibration").closed_forms()
    n = 0
    for r in data["rows"]:
        for c in st.checks(r):
            if str(c["source"]).startswith("cf:"):
                assert float(st._closed(closed, c["source"][3:])) == pytest.approx(
                    c["model"], rel=1e-12
                ), r["id"]
                n += 1
    assert n >= 29
    with pytest.raises(KeyError):
        st._closed(closed, "s001_closure_counts.N12_complete.no_such_count")


def test_every_source_names_a_study(st, data):
    """A check's source is 'cal:' / 'cf:' (seed-calibration) or '<study>:<JSON key>' with a
    study that exists, so each number can be traced and re-run."""
    names = set()
    for path in (ROOT / "studies").glob("*.py"):
        m = re.search(r'^NAME = "([\w-]+)"', path.read_text(encoding="utf-8"), re.M)
        if m:
            names.add(m.group(1))
    for r in data["rows"]:
        for c in st.checks(r):
            prefix = str(c["source"]).split(":", 1)[0]
            assert prefix in {"cal", "cf"} | names, (r["id"], c["source"])


def test_cramer_rows_are_what_the_study_gives(st, data, tmp_path):
    """Rows 0.1, 0.4, 0.5 quote the cramer study's summary: re-run it (quick: 256 samples per
    revolution; these keys agree with the full run to 1e-4) and compare each number."""
    import json

    js = tmp_path / "cramer.json"
    rc = _load("cramer").main(["--quick", "--no-plots", "--out", str(tmp_path), "--json", str(js)])
    assert rc in (0, None)
    summary = json.loads(js.read_text(encoding="utf-8"))
    n = 0
    for r in data["rows"]:
        for c in st.checks(r):
            src = c["source"]
            if not src.startswith("cramer:"):
                continue
            m = re.fullmatch(r"cramer:(\w+)(?:\[(\d+)\])?( / 5 .*)?(?: \(.*\))?", src)
            assert m, src
            value = summary[m.group(1)]
            value = value[int(m.group(2))] if m.group(2) else value
            value = value / 5 if m.group(3) else value
            assert value == pytest.approx(c["model"], rel=1e-3), (r["id"], src)
            n += 1
    assert n == 3
