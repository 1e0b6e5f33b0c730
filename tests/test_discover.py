"""Discovery after the catalog (issue 41): out-of-catalog structure on generated records with
known truth is modelled in the right frame with the speed exponent within 2 standard errors;
clean records get nothing; catalog physics stays named by the catalog; the model never
carries a catalog name and the verdict stays ``unexplained``."""

from __future__ import annotations

import numpy as np
import pytest

from encdesign.diagnose import export_candidates
from encdesign.diagnose._dispatch import diagnose, load_candidates
from encdesign.physics._effects import CATALOG_MULTIHEAD
from encdesign.physics._sensor_effects import CATALOG_REFERENCE
from encdesign.simulate._outside import outside_record
from tests.helpers import validate_diagnosis


def _models(doc) -> list[dict]:
    return [u["model"] for u in doc["unexplained"] if u.get("model") and u["model"]["terms"]]


def _terms(doc) -> list[dict]:
    return [t for m in _models(doc) for t in m["terms"]]


def _no_catalog_name(doc) -> None:
    names = {*CATALOG_MULTIHEAD, *CATALOG_REFERENCE} | {e["name"] for e in doc["effects"]}
    for m in _models(doc):
        said = {
            m["frame"],
            *(t["frame"] for t in m["terms"]),
            *(t["modulation"] for t in m["terms"]),
        }
        assert not (said & names), said
        assert m["outside_catalog"] is True


@pytest.mark.parametrize(("cls", "kind"), [("torque_ripple", "multihead"), ("speed_lag", "sensor")])
def test_speed_law_in_the_shaft_frame_with_its_exponent(cls, kind):
    rec, truth = outside_record(np.random.default_rng(41), cls, 5.0, kind, n_rows=3000)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert d.verdict == "unexplained", d.doc["report"]
    line = truth["line"][1]
    mine = [t for t in _terms(d.doc) if t["line_kind"] == "order" and t["value"] == line]
    assert mine, d.doc["report"]
    t = mine[0]
    assert (t["frame"], t["modulation"]) == ("shaft", "speed"), d.doc["report"]
    sc = t["scaling"]
    assert abs(sc["beta"] - truth["beta"]) <= 2 * sc["beta_se"], sc
    # the gain when it entered (not a rounding-level 0 or 1e-11 when a later term spans it)
    assert t["heldout_gain_chi2"] > 1.0 and t["inclusion_probability"] >= 0.6
    assert t["heldout_gain_drop_one_chi2"] <= t["heldout_gain_line_chi2"] + 1e-9
    m = next(m for m in _models(d.doc) if t in m["terms"])
    assert m["heldout_gain_chi2"] == t["heldout_gain_line_chi2"] > 0
    _no_catalog_name(d.doc)
    assert "discovered (outside the catalog)" in d.doc["report"]
    if cls == "torque_ripple":
        assert "7 pole pairs" in t["reading"] and "inertia" in t["reading"], t["reading"]


def test_a_defect_of_one_head_is_on_that_head_only():
    rec, truth = outside_record(np.random.default_rng(42), "head_defect", 5.0, "multihead", 3000)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert d.verdict == "unexplained"
    mine = [t for t in _terms(d.doc) if t["value"] == truth["line"][1]]
    assert mine and mine[0]["frame"] == truth["frame"], d.doc["report"]
    assert mine[0]["heads"] == [f"h{truth['frame'].split()[1]}"]
    _no_catalog_name(d.doc)


@pytest.mark.parametrize("kind", ["multihead", "sensor"])
def test_clean_records_get_nothing(kind):
    for seed in range(3):
        rec, _ = outside_record(np.random.default_rng([43, seed]), "clean", 0.0, kind, 3000)
        d = diagnose(rec)
        assert not _terms(d.doc), d.doc["report"]


def test_catalog_physics_stays_the_catalogs():
    """A vibration at a fixed frequency is a catalog effect: named by the catalog, and
    discovery models nothing there."""
    rec, truth = outside_record(np.random.default_rng(44), "fixed_hz", 8.0, "multihead", 3000)
    d = diagnose(rec)
    assert "vibration" in [e["name"] for e in d.effects], d.doc["report"]
    f0 = truth["line"][1]
    assert not [t for t in _terms(d.doc) if t["line_kind"] == "hz" and abs(t["value"] - f0) < 1]


def test_export_candidates_round_trip(tmp_path):
    """A discovered model written as a --candidates file is named, under its own name, in
    a later diagnosis of a similar record (another seed)."""
    rec, _ = outside_record(np.random.default_rng(45), "torque_ripple", 5.0, "multihead", 3000)
    d = diagnose(rec)
    path = tmp_path / "discovered.py"
    names = export_candidates(d.doc, path)
    assert names and all(n.startswith("discovered_") for n in names), names
    assert not set(names) & {*CATALOG_MULTIHEAD, *CATALOG_REFERENCE}
    cands = load_candidates(path)
    assert [c.name for c in cands] == names
    rec2, _ = outside_record(np.random.default_rng(46), "torque_ripple", 5.0, "multihead", 3000)
    d2 = diagnose(rec2, candidates=cands)
    validate_diagnosis(d2.doc)
    assert d2.verdict == "missing_physics", d2.doc["report"]
    named = [e for e in d2.effects if e["name"] in names]
    assert named, d2.doc["report"]
    beta = named[0]["params"]["beta"]["value"]
    assert abs(beta + 2.0) < 0.5, named[0]["params"]
    assert export_candidates({"unexplained": []}, tmp_path / "none.py") == []
    assert not (tmp_path / "none.py").exists()
