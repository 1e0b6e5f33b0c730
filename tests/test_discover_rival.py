"""Catalog names re-tested beside the discovered model (issue 41, session 32,
:mod:`encdesign.diagnose.engine._discover_rival`): a catalog effect named on a part of an
out-of-catalog structure is refused once discovery models that structure; a catalog effect
that is really there keeps its name beside it. A true catalog effect beside a discovered
remainder that takes most of its gain once fitted without it keeps its name too, where its own
held-out gain is the larger (session 33): ``tests/test_order_step_zeros.py``, training seed
7740 record 7 (a true ``eccentricity_shift`` and an ``order 2, disk`` remainder)."""

from __future__ import annotations

import numpy as np

from encdesign.diagnose import FinderSettings
from encdesign.diagnose._dispatch import diagnose
from encdesign.io import Recording
from encdesign.simulate._outside import NOISE_RAD, outside_record
from tests.helpers import validate_diagnosis

ROWS = 1500
RULE_PREFIX = "beside the discovered model"  # _discover_rival.RULE_PREFIX (runs on main)


def _record():
    """Training seed 8030: a 20x shaft-frame order 9 whose amplitude follows the speed
    (exponent 1). Main (839becf) named ``beam_tilt_axial`` beside the discovered law: the
    order moved the fitted head placements, which left head-specific low orders."""
    return outside_record(np.random.default_rng(8030), "speed_lag", 20.0, "multihead", ROWS)


def _law(doc: dict, order: int) -> dict:
    terms = [
        t
        for u in doc["unexplained"]
        for t in (u.get("model") or {}).get("terms", ())
        if t["line_kind"] == "order" and t["value"] == order
    ]
    assert terms, doc["report"]
    return terms[0]


def test_a_catalog_name_on_a_part_of_a_discovered_structure_is_refused():
    rec, truth = _record()
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert d.verdict == "unexplained", d.doc["report"]
    assert d.doc["effects"] == [], [e["name"] for e in d.doc["effects"]]
    refused = [r for r in d.doc["rejected"] if r["reason"].startswith(RULE_PREFIX)]
    assert [r["name"] for r in refused] == ["beam_tilt_axial"], d.doc["rejected"]
    assert "round" not in refused[0]  # after the selection, as the backward check
    assert {"bic_min", "located_share_min"} <= set(refused[0]["rules"])
    assert "dBIC {" not in refused[0]["reason"]
    assert refused[0]["delta_bic"] > -FinderSettings().bic_min  # its dBIC beside the model
    t = _law(d.doc, truth["line"][1])
    assert (t["frame"], t["modulation"]) == ("shaft", "speed")
    assert abs(t["scaling"]["beta"] - truth["beta"]) <= 2 * t["scaling"]["beta_se"]


def test_a_catalog_effect_that_is_there_keeps_its_name_beside_a_discovered_one():
    """The same record with a true catalog ``vibration`` added (a fixed frequency, each run
    its own amplitude and phase, 10x the noise): it stays named, and the order stays
    discovered in its frame."""
    rec, truth = _record()
    rng = np.random.default_rng([8030, 1])
    t, run = np.asarray(rec.columns["t"]), np.asarray(rec.columns["run"], int)
    runs = int(run.max()) + 1
    amp = 10 * NOISE_RAD * rng.uniform(0.6, 1.0, runs)[run]
    vib = amp * np.sin(2 * np.pi * 31.3 * t + rng.uniform(0, 2 * np.pi, runs)[run])
    cols = dict(rec.columns)
    for k in range(4):
        cols[f"h{k}"] = np.asarray(cols[f"h{k}"]) + vib
    d = diagnose(Recording(rec.kind, rec.meta, cols))
    validate_diagnosis(d.doc)
    assert [e["name"] for e in d.doc["effects"]] == ["vibration"], d.doc["report"]
    f = d.doc["effects"][0]["params"]["frequency_hz"]["value"]
    assert abs(f - 31.3) < 0.5  # a run is 1 s long: 1 Hz apart is one bin
    refused = {r["name"] for r in d.doc["rejected"] if r["reason"].startswith(RULE_PREFIX)}
    assert "vibration" not in refused  # (main's false beam_tilt_axial is, as above)
    assert _law(d.doc, truth["line"][1])["frame"] == "shaft"  # the structure stays discovered


def test_a_vibration_on_a_part_of_a_discovered_ring_down_is_refused():
    """Training seed 8074 (session 34): a mode rung at the start of each run (``fixed_hz``,
    5x the noise, its own Q). The catalog's steady ``vibration`` takes the mean of each run's
    ring-down, and the discovered ``ringing`` term at its frequency keeps the decay beside it.
    Main (e8089bd) named ``vibration`` beside the discovered term: the effect failed the
    rules beside it, but the term's held-out gain beside it was below the effect's whole. Per
    term, the discovered term in the effect's place (a fixed frequency) that keeps a gain
    past the catalog's gain rules beside it holds the larger structure: the name is refused
    and the ring-down is discovered whole."""
    rec, truth = outside_record(
        np.random.default_rng([8074, 41, 5]), "fixed_hz", 5.0, "multihead", ROWS
    )
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert d.verdict == "unexplained", d.doc["report"]
    assert [e["name"] for e in d.doc["effects"]] == [], d.doc["report"]
    refused = [r for r in d.doc["rejected"] if r["reason"].startswith(RULE_PREFIX)]
    assert [r["name"] for r in refused] == ["vibration"], d.doc["rejected"]
    assert "in its place" in refused[0]["reason"], refused[0]["reason"]
    terms = [
        t
        for u in d.doc["unexplained"]
        for t in (u.get("model") or {}).get("terms", ())
        if t["line_kind"] == "hz" and abs(t["value"] - truth["line"][1]) < 0.5
    ]
    assert terms and terms[0]["frame"] == "hz", d.doc["report"]
    assert {t["modulation"] for t in terms} == {"ringing"}, terms
