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
        "check": {"model": 1.0, "model_sd": 0.1, "seed": 1.1, "seed_sigma": 0.1, "kind": "predict"},
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
    closed = {
        r["check"]["source"][3:]: r["check"]["model"]
        for r in d["rows"]
        if str(r.get("check", {}).get("source", "")).startswith("cf:")
    }
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
        f"{r['check']['source'][4:]}": dict(
            key=r["check"]["source"].split("/")[1],
            model=r["check"]["model"],
            model_sd=r["check"]["model_sd"],
            kind=r["check"]["kind"],
        )
        for r in d["rows"]
        if str(r.get("check", {}).get("source", "")).startswith("cal:")
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
