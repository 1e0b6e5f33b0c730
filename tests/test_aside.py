"""Issue 43 (peak memory per process): whole-record arrays set aside in a temporary file while
a stage that does not read them runs (``engine._aside``), and the engine's use of it: the
selection's residuals are not in memory during the detection bounds, and come back to the
figures' data bit for bit."""

from __future__ import annotations

import hashlib
import weakref

import numpy as np

import encdesign.diagnose.engine._engine as engine
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.engine._aside import SetAside
from tests.test_diagnose import _bench


def _digest(a: np.ndarray) -> tuple:
    return a.dtype.str, a.shape, hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


def test_set_aside_arrays_come_back_bit_for_bit():
    rng = np.random.default_rng(20262901)
    f = rng.normal(size=(1001, 4))
    f[3, 1], f[5, 2], f[7, 0] = np.nan, -0.0, np.inf
    arrays = [f, rng.integers(-9, 9, size=17, dtype=np.int32), np.zeros((0, 3)), f[:, 1]]
    want = [_digest(a) for a in arrays]
    aside = SetAside(arrays)
    back = aside.restore()
    assert [_digest(a) for a in back] == want
    assert all(b is not a for a, b in zip(arrays, back))


def test_selection_residuals_are_out_of_memory_during_the_bounds(monkeypatch):
    """The base and final residuals the selection returns are freed while the detection
    bounds run (on main both stay in memory: 2 x 8 C bytes per row at the bounds' peak) and
    the figures' data gets them back unchanged."""
    seen: dict = {}
    select, bounds = engine.select, engine.detection_bounds

    def selected(*a, **k):
        sel = select(*a, **k)
        seen["refs"] = [weakref.ref(sel.base_resid), weakref.ref(sel.final_resid)]
        seen["digests"] = [_digest(sel.base_resid), _digest(sel.final_resid)]
        return sel

    def bounded(*a, **k):
        seen["alive_in_bounds"] = [r() is not None for r in seen["refs"]]
        return bounds(*a, **k)

    monkeypatch.setattr(engine, "select", selected)
    monkeypatch.setattr(engine, "detection_bounds", bounded)
    rec, _ = _bench(6, vibration_hz=37.0)
    d = diagnose(rec)
    assert [e["name"] for e in d.effects] == ["vibration"]
    assert seen["alive_in_bounds"] == [False, False]
    pd = d.plot_data
    assert [_digest(pd.base_resid), _digest(pd.final_resid)] == seen["digests"]
