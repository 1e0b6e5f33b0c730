"""The discovery benchmark's oracle (``benchmarks/discovery.py``, issue 41, session 32): on an
SDS record the base residual is the record's exact structure and noise after the base model
(no noise source outside the oracle's ``eps``), and the finder's level over the true one is
the product of its parts."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))

import discovery as B  # noqa: E402

from encdesign.diagnose._dispatch import diagnose  # noqa: E402
from encdesign.diagnose.engine import _engine  # noqa: E402
from encdesign.simulate._outside import outside_record  # noqa: E402

SEED = [8043, 0, 9, 1, 0]  # training seed (session 32): a 5x sensor_frame case


def _oracle(monkeypatch, twin_noise: bool = False) -> dict:
    monkeypatch.setattr(_engine, "discover", B._capture)
    monkeypatch.setattr(_engine, "_document", B._capture_document)
    if twin_noise:  # the structure-free twin keeps a noise the record's eps does not hold
        real = B.outside_record

        def leaky(rng, cls, size, kind, rows, noise=True):
            return real(rng, cls, size, kind, rows, noise=noise or size == 0.0)

        monkeypatch.setattr(B, "outside_record", leaky)
    B._CAP.clear()
    rec, _ = outside_record(np.random.default_rng(SEED), "sensor_frame", 5.0, "sds", 3000)
    diagnose(rec)
    return B._oracle("sensor_frame", 5.0, "sds", SEED, 3000)


@pytest.fixture(scope="module")
def oracle():
    mp = pytest.MonkeyPatch()
    try:
        yield _oracle(mp)
    finally:
        mp.undo()


def test_the_base_residual_is_the_records_structure_and_noise(oracle):
    """The base residual equals the exact structure plus noise after the base's columns to
    1e-2 (0.1-0.5 % on training records): the finder's SDS level, 1.4-1.8 times the true
    one on every case, is not fed by a noise source the oracle leaves out."""
    assert oracle["oracle_noncentrality"] > 100
    assert oracle["oracle_closure"] < 1e-2


def test_the_closure_sees_a_noise_the_oracle_leaves_out(monkeypatch):
    """The check can fail: a structure-free twin that keeps its own noise (so the oracle's
    ``mu + eps`` hold a noise the record does not) leaves the base residual far from them."""
    assert _oracle(monkeypatch, twin_noise=True)["oracle_closure"] > 0.3


def test_the_level_ratio_is_the_product_of_its_parts(oracle):
    """``noise_finder_over_true`` = raw estimate over the true differences' level x widening
    x common factor x the differences' true level over the structure's."""
    parts = oracle["noise_finder_over_true_parts"]
    assert set(parts) == {"estimate", "widening", "common_factor", "level_mix", "product"}
    assert parts["product"] == pytest.approx(oracle["noise_finder_over_true"], rel=1e-9)
    assert parts["widening"] > 1.0 and parts["common_factor"] >= 1.0
    lv = oracle["noise_finder_run_means"]
    assert parts["widening"] == lv["widening"] and parts["common_factor"] == lv["common_factor"]


def test_sds_noise_parts_keep_the_jitter_and_the_rounding_apart():
    """``outside_record(..., sds_noise_parts=(jitter, rounding))``
    (``benchmarks/sds_run_mean_levels.py``): the rounding alone puts every edge on the
    100 MHz clock's grid, the jitter alone none, and both are the default record."""
    from encdesign.simulate._conceal_sds import CLOCK_S

    def edges(parts=(True, True)):
        rec, _ = outside_record(
            np.random.default_rng(8043), "clean", 0.0, "sds", sds_noise_parts=parts
        )
        return np.asarray(rec.columns["t"], float)

    on_grid = lambda t: np.abs(t / CLOCK_S - np.round(t / CLOCK_S)) < 1e-6  # noqa: E731
    both, jitter, rounding = edges(), edges((True, False)), edges((False, True))
    assert both.size and np.all(on_grid(both)) and np.all(on_grid(rounding))
    assert not np.any(on_grid(jitter))
    assert not np.array_equal(both, rounding)  # the jitter moves edges by whole ticks too


def test_the_ideal_test_ceiling_is_its_closed_form_and_below_the_known_level():
    """``discovery_acceptance.ideal_power`` (session 42): with the level known it is the
    noncentral chi-square tail at the larger threshold; with the level estimated from ``nu``
    degrees of freedom it is the noncentral F tail at the same false-alarm probability, below
    the known level's and approaching it as ``nu`` grows; a case without numbers gives
    ``None`` and makes the ceiling over its cases ``None``; read at the locating view's own
    threshold a growth or a step pays the ``modulated_orders`` view's search."""
    import discovery_acceptance as A
    from scipy import stats

    c = {
        "oracle_noncentrality": 30.0,
        "true_dof": 2,
        "threshold_true_raw_chi2": 21.3,
        "threshold_locate_chi2": 23.1,
        "noise_finder_run_means": {"dof": 36},
    }
    known = A.ideal_power(c, estimated=False)
    assert known == pytest.approx(stats.ncx2.sf(23.1, 2, 30.0), rel=1e-12)
    est = A.ideal_power(c, estimated=True)
    assert est is not None and known is not None and 0.2 < est < known < 1.0
    big = A.ideal_power({**c, "noise_finder_run_means": {"dof": 10**6}}, estimated=True)
    assert big == pytest.approx(known, rel=1e-3)
    assert A.ideal_power({**c, "noise_finder_run_means": {}}, estimated=True) is None
    assert A._ceiling([c, c], estimated=False) == pytest.approx((2 * known, 2))
    assert A._ceiling([c, {"true_dof": 2}], estimated=False) is None
    # the locating view's own threshold: a static line is read as before; a step pays the
    # modulated view's search over 2 K switch shapes (its threshold above the orders view's)
    # or keeps half its power in the static scan; a growth keeps 3/4 there
    assert A.ideal_power(c, estimated=True, views=True) == pytest.approx(est, rel=1e-12)
    step = {**c, "truth": {"modulation": "step"}}
    (k0, t0), (k1, t1) = A._view_routes(step)
    assert (k0, t0) == (0.5, 23.1) and k1 == 1.0 and t1 > t0 + 3
    growth = {**c, "truth": {"modulation": "growth"}}
    (g0, _), (_, tg) = A._view_routes(growth)
    assert g0 == 0.75 and t0 < tg < t1
    assert A.ideal_power(step, estimated=True, views=True) < est


def test_the_rounding_ratio_is_its_prediction_over_disks_and_spreads_from_disk_to_disk():
    """``benchmarks/sds_run_mean_levels.disk_ratio_spread`` (session 42): three moving sensors
    a third of a revolution apart on 10^7 ticks (a third of a tick apart) give a rounding whose
    common component has 1/4 of the differences' variance pooled over disks (the closed form
    ``predicted_rounding_ratio`` squared, within 10 %), while one disk's own ratio ranges
    beyond 0.1 to 0.8 (why the clock alone cannot set one record's common level)."""
    import sds_run_mean_levels as L

    psi = np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3])
    assert L.predicted_rounding_ratio(psi) ** 2 == pytest.approx(0.25, rel=1e-6)
    pooled, each = L.disk_ratio_spread(psi, 1e7, 200, np.random.default_rng(42), disks=300)
    assert pooled == pytest.approx(0.25, rel=0.1)
    assert each.size == 300 and each.min() < 0.1 and each.max() > 0.8
