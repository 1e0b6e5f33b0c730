"""Typed results of a diagnosis (issue 22 item 1): ``Effect``, ``Finding``, ``Refusal``,
``Alternative``, ``Confounded`` and ``Diagnosis`` are equinox Modules whose ``to_json`` gives
back the engine's document unchanged, with invariants checked when they are built."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from encdesign._errors import DiagnosisError
from encdesign.diagnose import Diagnosis
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose._engine import run_engine
from encdesign.diagnose._multihead import MULTIHEAD
from encdesign.diagnose._results import Alternative, Confounded, Effect, Finding, Refusal
from encdesign.io._study import to_jsonable
from tests.helpers import stepped_sensor_record, validate_diagnosis


def _dump(doc) -> str:
    return json.dumps(to_jsonable(doc))


@pytest.mark.parametrize(
    "make",
    [
        lambda: stepped_sensor_record(3, hysteresis_rad=4e-4)[0],
        lambda: stepped_sensor_record(5, n_steps=60)[0],
        lambda: stepped_sensor_record(6, n_steps=60, both=False)[0],
    ],
    ids=["hysteresis", "clean", "one_direction"],
)
def test_to_json_is_the_engine_document(make):
    """For generated records, the typed diagnosis gives back the engine's document: the
    same JSON text (keys and their order), and typed attributes."""
    doc, plot = run_engine(MULTIHEAD, make())
    d = Diagnosis.from_json(doc, plot)
    assert _dump(d.to_json()) == _dump(doc)
    assert _dump(d.doc) == _dump(doc) and d["verdict"] == doc["verdict"]
    validate_diagnosis(d.to_json())
    assert all(isinstance(e, Effect) for e in d.effects)
    assert all(isinstance(f, Finding) for f in d.unexplained)
    assert all(isinstance(r, Refusal) for r in (*d.rejected, *d.not_testable))
    assert [e.name for e in d.effects] == [e["name"] for e in doc["effects"]]
    for e in d.effects:  # back compatibility: entries read like the JSON
        assert e["name"] == e.name and e["params"] is e.params
        assert isinstance(e.notes, tuple)
        assert all(isinstance(c, Alternative) for c in e.confounded_with or ())
    for r in d.rejected:
        assert r.rule is not None and r.rule in (r.rules or (r.rule,))
    # each named effect's own contribution is there for the figures
    assert set(plot.effect_contributions) == {e.name for e in d.effects if e.delta_bic is not None}
    for v in plot.effect_contributions.values():
        assert v.shape == np.shape(plot.final_resid)


def test_diagnose_returns_typed_and_json_roundtrip(tmp_path):
    rec, _ = stepped_sensor_record(4, hysteresis_rad=4e-4)
    d = diagnose(rec, plots=tmp_path)
    assert d.verdict == "missing_physics" and d.effects[0].name == "direction_hysteresis"
    assert d.to_json()["plots"] and "plots" in d.other
    again = Diagnosis.from_json(json.loads(_dump(d.to_json())))
    assert _dump(again.to_json()) == _dump(d.to_json())


def test_invariants_are_checked():
    ok: dict[str, Any] = dict(
        name="x", params={}, rms_after=1.0, heldout_rms_after=1.0, delta_bic=-5.0
    )
    Effect(**ok, collinearity=0.5)
    with pytest.raises(DiagnosisError, match="collinearity"):
        Effect(**ok, collinearity=1.5)
    with pytest.raises(DiagnosisError, match="name"):
        Effect(**{**ok, "name": ""}, collinearity=None)
    with pytest.raises(DiagnosisError, match="where"):
        Finding(where={"orders": []}, rms=1.0)
    with pytest.raises(DiagnosisError, match="rule"):
        Refusal(name="x", reason="r", rule="a", rules=("b",))
    with pytest.raises(DiagnosisError, match="pair"):
        Confounded(pair=("a", "a"), correlation=0.99, delta_bic=0.1, separate_by="-")
    with pytest.raises(DiagnosisError, match="missing_physics"):
        Diagnosis(
            verdict="missing_physics",
            status="ok",
            effects=(),
            unexplained=(),
            rejected=(),
            not_testable=(),
            confounded=(),
            other={},
            key_order=(),
        )
