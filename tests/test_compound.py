"""Several catalog effects at once on a multihead record with a reference (issue 44 B):
``encdesign.simulate._compound`` and the finder on it."""

from __future__ import annotations

import types

import numpy as np
import pytest
from helpers import sweep

from encdesign.diagnose import FinderSettings
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.kinds.multihead._runout import _bt_orders_supported
from encdesign.simulate._compound import COMPOUND_EFFECTS, GEOMETRIES, simulate_compound


def test_generator_layouts_and_truth():
    for g in GEOMETRIES:
        rec, truth = simulate_compound(np.random.default_rng(1), geometry=g, samples_per_run=300)
        heads = [c for c in rec.columns if c.startswith("h")]
        assert len(heads) == len(GEOMETRIES[g])
        assert "theta_ref" in rec.columns
        assert truth["effects"] == list(COMPOUND_EFFECTS)
        assert truth["runout_orders"] == [1, 2, 3]
    with pytest.raises(ValueError):
        simulate_compound(np.random.default_rng(1), geometry="7+1")


def _ctx(theta, run, resid_noise):
    oh = np.eye(int(run.max()) + 1)[run]
    return types.SimpleNamespace(
        rows={"theta": theta, "run_onehot": oh},
        noise=resid_noise,
        settings=FinderSettings(),
    )


def test_runout_orders_follow_the_record_not_a_share_of_the_strongest():
    """A weak order 3 (a twentieth of order 1's power, far above the noise) is supported; a
    strong order 1 over a fraction of a turn more than whole turns leaks into orders 2 and 3
    of a one-order fit, and the joint fit does not take the leak for an order."""
    rng = np.random.default_rng(7)
    n, C = 3000, 4
    theta = np.linspace(0, 2 * np.pi * 3.4, n)
    run = np.zeros(n, int)
    beta = rng.uniform(0.5, 1.0, C)
    noise = np.full(C, 1e-7)
    strong = 40e-7 * np.sin(theta + 0.3)[:, None] * beta
    weak3 = 9e-7 * np.sin(3 * theta + 1.1)[:, None] * beta
    eps = rng.normal(0, 1e-7, (n, C))
    all_on = np.ones(3, bool)
    ctx = _ctx(theta, run, noise)
    got = _bt_orders_supported(ctx, strong + eps, all_on)
    assert got.tolist() == [True, False, False]
    got = _bt_orders_supported(ctx, strong + weak3 + eps, all_on)
    assert got.tolist() == [True, False, True]
    # the share rule it replaces would have dropped order 3 (a twentieth of order 1's power)
    assert (9 / 40) ** 2 < 0.1


# ``make test`` runs the kept cases; the others are the ``sweep`` tier (``make
# test-sweeps``; session 31, CI time)
@pytest.mark.parametrize(
    ("geometry", "seed"),
    sweep(
        [("4i+1", 501), ("4i+1", 503), ("3+1", 501), ("3+1", 503)],
        (("4i+1", 501), ("3+1", 503)),
    ),
)
def test_three_effects_at_once_all_named_nothing_they_explain_left(geometry, seed):
    """Vibration, a beam tilt with axial runout at orders 1-3 and a weaker interpolation error
    on irregular heads with a reference: all three named, the runout's every order fitted, and
    nothing left unexplained (today's main left the order 3 on the heads, issue 44 B)."""
    rec, truth = simulate_compound(np.random.default_rng([seed, 44]), geometry=geometry)
    d = diagnose(rec).doc
    names = sorted(e["name"] for e in d["effects"])
    assert names == sorted(truth["effects"]), (names, d["rejected"])
    bt = next(e for e in d["effects"] if e["name"] == "beam_tilt_axial")
    assert bt["derived"]["orders_fitted"]["value"] == truth["runout_orders"]
    assert d["unexplained"] == [], [(f["view"], f["where"]) for f in d["unexplained"]]


# ``make test`` runs the kept cases; the others are the ``sweep`` tier (``make
# test-sweeps``; session 31, CI time)
@pytest.mark.parametrize("seed", sweep([501, 502], (501,)))
def test_a_weak_effect_is_not_refused_for_unrelated_structure(seed):
    """A strong vibration, a weak interpolation error and an out-of-catalog order on one head
    (12x the noise): the interpolation error explains all of what its own fitted error shows
    (the line-phase view on its heads), however small a share of everything located it is
    (today's main refused it, ``located_share_min``: 11-13 % of all located structure); the
    one-head order is left unexplained on its head."""
    rec, truth = simulate_compound(
        np.random.default_rng([seed, 44]),
        geometry="4i+1",
        effects=("vibration", "interpolation_error"),
        one_head_order=12.0,
    )
    d = diagnose(rec).doc
    names = {e["name"] for e in d["effects"]}
    assert {"vibration", "interpolation_error"} <= names, d["rejected"]
    # (a candidate that is not in the record may still be refused by it: a beam tilt fitted
    # to a part of another structure)
    refused = [r for r in d["rejected"] if r["rule"] == "located_share_min"]
    assert not [r for r in refused if r["name"] in truth["effects"]], refused
    m, k = truth["where"]["orders"][0], truth["where"]["heads"][0]
    at_m = [
        u
        for u in d["unexplained"]
        if any(abs(o - m) < 0.15 for o in u["where"]["orders"]) and k in u["where"]["heads"]
    ]
    assert at_m, [(u["view"], u["where"]) for u in d["unexplained"]]
