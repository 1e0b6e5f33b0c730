"""Stage 4 (``_select``) rules on pieces of larger structures (issue 44, session 17): a line
fixed in Hz in a broad band, and a catalog order set's top order in an out-of-catalog comb."""

import numpy as np

from encdesign.diagnose import diagnose
from encdesign.simulate import draw_plan, fix_plan, simulate_plan


def _bench(seed: int, kind: str, case: str, effect: str | None = None):
    rng = np.random.default_rng([seed, 17])
    plan = draw_plan(rng, kind, case)
    if effect is not None:
        plan["effects"] = [effect]
        plan = fix_plan(plan, rng)
    return simulate_plan(rng, plan)


def test_a_line_fixed_in_hz_is_not_named_for_a_slice_of_a_chirp():
    # a chirp on a sensor sweeps through a band; a vibration line at one frequency in it
    # lowers the criterion (main named it) but clears only a sliver of the band
    rec, truth = _bench(5524, "sensor", "out_of_catalog", "chirp_one_head")
    d = diagnose(rec).doc
    assert [e["name"] for e in d["effects"]] == []
    assert d["verdict"] == "unexplained"
    ref = [r for r in d["rejected"] if r["name"] == "vibration"]
    assert ref and "broad band" in ref[0]["reason"]
    lo, hi = truth["where"]["frequencies_hz"]
    bands = [u["where"]["frequencies_hz"] for u in d["unexplained"] if u["view"] == "band"]
    assert any(a <= hi and b >= lo for a, b in bands)


def test_a_vibration_line_of_its_own_is_still_named():
    rec, _ = _bench(5528, "sensor", "single", "vibration")
    assert [e["name"] for e in diagnose(rec).doc["effects"]] == ["vibration"]


def test_signal_shape_is_not_named_for_the_tooth_of_a_comb_above_its_orders():
    # an out-of-catalog radial order 14 with its sidebands: signal_shape (orders 3-12) fitted
    # mostly at its top order 12, the sideband (main named it)
    rec, truth = _bench(5518, "quadrature", "out_of_catalog", "radial_order")
    d = diagnose(rec).doc
    assert [e["name"] for e in d["effects"]] == []
    assert any(r["rule"] == "edge_order" for r in d["rejected"] if r["name"] == "signal_shape")
    m = truth["where"]["orders"][0]
    assert any(m in u["where"]["orders"] for u in d["unexplained"])


def test_a_signal_shape_of_its_own_is_still_named():
    rec, _ = _bench(5503, "quadrature", "compound")
    assert [e["name"] for e in diagnose(rec).doc["effects"]] == ["signal_shape"]


def test_a_tie_that_fits_better_says_the_criterion_decided():
    """A ``tie_chi2`` partner that fits better than the named effect (its chi-square lower,
    only its extra parameters charged more) is never said to fit "as well" (issue 44: the
    truth fitted 56.7 lower and read as "fits as well (chi-square -56.7)")."""
    from encdesign.diagnose.engine._evidence import tie_reason
    from encdesign.diagnose.engine._settings import FinderSettings

    s = FinderSettings()
    better = tie_reason("vibration", -56.7, 0.984, -1631.7, -1669.1, s)
    assert "fits as well" not in better and "lower by 56.7" in better
    assert "information criterion" in better and "-1631.7" in better
    alike = tie_reason("vibration", 3.2, 0.984, -1631.7, -1669.1, s)
    assert "fits as well (chi-square +3.2" in alike


def test_one_residual_is_held_while_the_selection_scans(monkeypatch):
    """Issue 43 (peak memory): each scan the selection makes of its current residual has no
    other residual of the selection beside it (on main the round's residual stayed alive
    through the scan after a candidate was named: the default argument of ``kept_resid``)."""
    import sys
    import weakref

    import encdesign.diagnose.engine._fit as fit_mod
    import encdesign.diagnose.engine._select as select_mod
    from tests.test_diagnose import _bench as bench

    made: list = []
    residual, locate = fit_mod.Fitter.residual, select_mod.locate
    alive_at_scans: list[int] = []

    def tracked(self, terms):
        r = residual(self, terms)
        made.append(weakref.ref(r))
        return r

    def scanned(prep, resid, *a, **k):
        if sys._getframe(1).f_code.co_name in {"select", "_select"}:  # the selection's scans
            alive_at_scans.append(sum(w() is not None and w() is not resid for w in made))
        return locate(prep, resid, *a, **k)

    monkeypatch.setattr(fit_mod.Fitter, "residual", tracked)
    monkeypatch.setattr(select_mod, "locate", scanned)
    rec, _ = bench(6, vibration_hz=37.0)
    d = diagnose(rec)
    assert [e["name"] for e in d.effects] == ["vibration"]
    assert len(alive_at_scans) >= 2  # the base's residual and the named effect's
    assert alive_at_scans == [0] * len(alive_at_scans)
