"""Issue 44 F: a verdict reports the smallest size of each catalog effect it did not name
(per head or sensor) the record would have revealed, against the final model (the base and
the named effects), and the bound holds on generated records: effects 1.5x above it are
named, effects at half of it are not (the larger count: ``benchmarks/detection_bounds.py``,
``benchmarks/detection_bounds_named.py``)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from encdesign.diagnose import diagnose
from encdesign.diagnose.engine._bounds import median_noncentrality
from encdesign.simulate import write_concealed_sds
from encdesign.simulate._conceal_sds import NOISE_RAD, SPEED_RAD_S
from tests.helpers import shared_diagnosis, validate_diagnosis

GEOM = dict(n_runs=8, n_moving=3, n_fixed=2, phi_ref=True)


def test_median_noncentrality_is_the_median():
    from scipy import stats

    for k, target in ((1, 15.0), (3, 26.0), (11, 120.0)):
        lam = median_noncentrality(k, target)
        assert abs(stats.ncx2.median(k, lam) - target) < 1e-4 * target
    assert median_noncentrality(4, 1.0) == 0.0  # the central median is above already


def _sds(tmp_path, key: int, tau_s: float):
    amp = max(tau_s * SPEED_RAD_S / NOISE_RAD, 1e-9)
    return write_concealed_sds(
        tmp_path / f"r{key}.toml",
        key=jax.random.key(key),
        effect="sensor_delay_step",
        amplitude_noise=amp,
        **GEOM,
    )


def test_sds_delay_step_bound_holds(tmp_path):
    """The bound per moving sensor of a clean sds bench is about this record: the same
    record (same noise, the step run in the middle half, as the bound states) with a step on
    m1 at 1.5x it is named, at half of it not. (Records with fresh noise have their own noise
    estimate, known to about +-20 % from 8 runs, so their own bound: the benchmark counts
    both, ``benchmarks/detection_bounds.py`` with and without ``--same``.)"""
    key = 940
    while True:
        key += 1
        rec, truth = _sds(tmp_path, key, 0.0)
        if 2 <= truth["params"]["first_run"] <= 6:  # the bound's middle half of 8 runs
            break
    d = diagnose(rec).doc
    validate_diagnosis(d)
    assert d["verdict"] == "consistent"
    bounds = {(b["effect"], b["where"]): b for b in d["detection_bounds"]}
    assert {("sensor_delay_step", f"m{m}") for m in range(3)} <= set(bounds)
    b = bounds[("sensor_delay_step", "m1")]
    assert b["unit"] == "s" and 1e-11 < b["bound"] < 1e-8
    assert "sensor_delay_step" in d["report"] and "smallest size" in d["report"]
    found = {}
    for factor in (1.5, 0.5):
        rec, _ = _sds(tmp_path, key, factor * b["bound"])
        found[factor] = "sensor_delay_step" in [e["name"] for e in diagnose(rec).doc["effects"]]
    assert found == {1.5: True, 0.5: False}, found


def _vibration_record(*args):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from detection_bounds import vibration_record

    return vibration_record(*args)


def test_bounds_of_the_effects_not_named_against_the_final_model():
    """A verdict that names an effect bounds the others, against the base and the named
    effect (``detection_bounds_reference``); the named effect itself is not bounded."""
    rec, rate = _vibration_record(904, 904, 3e-5, 0, None)
    rec, _ = _vibration_record(904, 904, 3e-5, 0, 0.23 * rate)  # a line far above the noise
    diag = diagnose(rec)
    d = diag.doc
    validate_diagnosis(d)
    assert d["verdict"] == "missing_physics"
    assert [e["name"] for e in d["effects"]] == ["vibration"]
    assert d["detection_bounds"] and not any(
        b["effect"] == "vibration" for b in d["detection_bounds"]
    )
    ip = [b for b in d["detection_bounds"] if b["effect"] == "interpolation_error"]
    assert [b["where"] for b in ip] == d["noise"]["channels"]
    assert all(b["bound"] > 0 for b in ip)
    ref = d["detection_bounds_reference"]
    assert ref["model"] == "base and named effects" and ref["named"] == ["vibration"]
    assert "vibration" in ref["terms"] and ref["room_for_another_effect"] is True
    assert "against the base model and the named effects (vibration)" in d["report"]
    assert [b.effect for b in diag.detection_bounds] == [b["effect"] for b in d["detection_bounds"]]


@pytest.mark.parametrize("seed", [903])
def test_multihead_vibration_bound_per_head(seed):
    diag = diagnose(_vibration_record(seed, seed, 0.0, 1, None)[0])
    d = diag.doc
    validate_diagnosis(d)
    if d["verdict"] != "consistent":
        pytest.skip(f"clean record {d['verdict']}")
    vib = [b for b in d["detection_bounds"] if b["effect"] == "vibration"]
    heads = d["noise"]["channels"]
    assert [b["where"] for b in vib] == heads
    sig = np.asarray(d["noise"]["per_channel"])
    assert [b.where for b in diag.detection_bounds if b.effect == "vibration"] == heads
    for b, s in zip(vib, sig):
        # a line of amplitude a on n rows carries a^2 n / (2 s^2): the bound sits where that
        # reaches the criterion's median (k = 2 R C + 1 parameters)
        assert b["set_by"] in ("bic_min", "view")
        assert 0.1 * s < b["bound"] < 100 * s


def _bench(name: str):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    import detection_bounds

    return getattr(detection_bounds, name)


def test_multihead_interpolation_error_bound_per_head():
    """Per head, the smallest signal offset (order L) a clean multihead record would have
    revealed; a record of the same geometry with fresh noise and the offset at 1.5x it on head
    1 shows it (named, or confounded with a vibration: at one speed per run order L is a line
    in time), at half of it not."""
    seed = 1531
    record, found = _bench("vibration_record"), _bench("_found")
    d = diagnose(record(seed, seed, 0.0, 1, None)[0]).doc
    validate_diagnosis(d)
    assert d["verdict"] == "consistent"
    ip = [b for b in d["detection_bounds"] if b["effect"] == "interpolation_error"]
    assert [b["where"] for b in ip] == d["noise"]["channels"]
    assert "interpolation_error" not in d.get("detection_bounds_not_covered", [])
    b = ip[1]
    assert b["parameter"] == "offset_a" and b["unit"] == "1" and b["bound"] > 0
    got = {}
    for factor, key in ((1.5, seed * 1000), (0.5, seed * 1000 + 500)):
        doc = diagnose(record(seed, key, 0.0, 1, None, factor * b["bound"])[0]).doc
        got[factor] = found(doc, "interpolation_error")
    assert got == {1.5: True, 0.5: False}, got


def test_reference_scale_error_bound(tmp_path):
    """The smallest scale error a clean sensor-against-reference record would have revealed;
    a record of the same geometry with fresh noise at 1.5x it shows it, at half of it not."""
    seed = 1532
    record = _bench("scale_record")
    d = diagnose(record(seed, seed, 0.0, tmp_path)).doc
    validate_diagnosis(d)
    assert d["verdict"] == "consistent"
    (b,) = [b for b in d["detection_bounds"] if b["effect"] == "scale_error"]
    assert b["parameter"] == "scale" and b["unit"] == "1" and 0 < b["bound"] < 1e-3
    got = {}
    for factor, key in ((1.5, seed * 1000), (0.5, seed * 1000 + 500)):
        doc = diagnose(record(seed, key, factor * b["bound"], tmp_path)).doc
        got[factor] = "scale_error" in [e["name"] for e in doc["effects"]]
    assert got == {1.5: True, 0.5: False}, got


def test_reference_interpolation_error_bound(tmp_path):
    """The smallest signal offset (order P) a clean sensor-against-reference record would have
    revealed; a record of the same geometry with fresh noise at 1.5x it shows it, at half of it
    not."""
    seed = 1533
    record = _bench("interp_ref_record")
    d = diagnose(record(seed, seed, 0.0, tmp_path)).doc
    validate_diagnosis(d)
    assert d["verdict"] == "consistent"
    (b,) = [b for b in d["detection_bounds"] if b["effect"] == "interpolation_error"]
    assert b["parameter"] == "offset_a" and b["unit"] == "1" and 0 < b["bound"] < 0.1
    got = {}
    for factor, key in ((1.5, seed * 1000), (0.5, seed * 1000 + 500)):
        doc = diagnose(record(seed, key, factor * b["bound"], tmp_path)).doc
        got[factor] = "interpolation_error" in [e["name"] for e in doc["effects"]]
    assert got == {1.5: True, 0.5: False}, got


@pytest.mark.parametrize("effect", ["cogging", "magnet_asymmetry", "coil_mismatch"])
def test_motion_bounds_hold(effect):
    """The smallest amplitude of each motion catalog effect at its lowest order a clean motion
    record would have revealed; a record of the same motor with fresh noise at 1.5x it shows
    it, at half of it not. (Motor 1537: 5 pole pairs, 12 slots, its cogging order 60 under
    the sampling's Nyquist order; motor 1534's cogging order 168 is above it.)"""
    seed = 1537
    record = _bench("motion_record")
    d = shared_diagnosis(record(seed, seed, 1, 0.0)).doc  # the clean record: one per process
    validate_diagnosis(d)
    assert d["verdict"] == "consistent"
    assert effect not in d.get("detection_bounds_not_covered", [])
    (b,) = [b for b in d["detection_bounds"] if b["effect"] == effect]
    assert b["parameter"] == "amplitude_rad" and b["unit"] == "rad" and 0 < b["bound"] < 1e-3
    order = int(b["at"].split()[1])
    got = {}
    for factor, key in ((1.5, seed * 1000), (0.5, seed * 1000 + 500)):
        doc = diagnose(record(seed, key, order, factor * b["bound"])).doc
        got[factor] = effect in [e["name"] for e in doc["effects"]]
    assert got == {1.5: True, 0.5: False}, got


def test_quadrature_signal_shape_bound():
    """The smallest radial amplitude of ``signal_shape`` (radial orders 3 and 4) a clean
    quadrature capture would have revealed; a capture of the same geometry with fresh noise
    at 1.5x it names it, at half of it not."""
    seed = 3102
    record = _bench("quadrature_record")
    d = diagnose(record(seed, seed, 3, 0.0)).doc
    validate_diagnosis(d)
    assert d["verdict"] == "consistent"
    assert "signal_shape" not in d["detection_bounds_not_covered"]
    bs = [b for b in d["detection_bounds"] if b["effect"] == "signal_shape"]
    assert [b["at"] for b in bs] == ["radial order 3", "radial order 4"]
    sigma = d["noise"]["per_channel"][0]
    for b in bs:
        assert b["parameter"] == "radial_amplitude" and b["where"] == "radius"
        assert 0.01 * sigma < b["bound"] < sigma
    got = {}
    for factor, key in ((1.5, seed * 1000), (0.5, seed * 1000 + 500)):
        doc = diagnose(record(seed, key, 4, factor * bs[1]["bound"])).doc
        got[factor] = "signal_shape" in [e["name"] for e in doc["effects"]]
    assert got == {1.5: True, 0.5: False}, got


@pytest.mark.parametrize(
    ("seed", "rule", "raised"), [(3103, "heldout_min", 1.0), (3220, "heldout_min", 3.0)]
)
def test_bound_beside_unexplained_structure_holds(seed, rule, raised):
    """Beside structure no catalog effect explains (a radial order above ``signal_shape``'s),
    a later round's candidate must still gain on held-out data with that structure in the
    folds (``heldout_min`` on the record itself; 3220 is a capture without ``t``, whose folds
    are phase sectors): the bound says so, and holds on captures with fresh noise. Its share
    (``located_share_min``) is measured where its own error shows (issue 44 B, session 15):
    a structure at another radial order does not raise it (3103 was set by the share of
    everything located before, at over 3x the clean bound; now by the held-out gain, at
    about 1.2x)."""
    record = _bench("quadrature_record")
    d0 = diagnose(record(seed, seed, 3, 0.0)).doc
    clean = d0["detection_bounds"][0]["bound"]
    extra = ((17, 20 * clean),)
    d = diagnose(record(seed, seed, 3, 0.0, more=extra)).doc
    validate_diagnosis(d)
    assert d["verdict"] == "unexplained"
    ref = d["detection_bounds_reference"]
    assert ref["model"] == "base" and ref["located_excess_chi2"] > 0
    b = d["detection_bounds"][0]
    assert b["set_by"] == rule and b["bound"] > raised * clean
    got = {}
    for factor, key in ((1.5, seed * 1000), (0.5, seed * 1000 + 500)):
        doc = diagnose(record(seed, key, 3, factor * b["bound"], more=extra)).doc
        got[factor] = "signal_shape" in [e["name"] for e in doc["effects"]]
    assert got == {1.5: True, 0.5: False}, got


def test_second_effect_bound_against_the_named_one():
    """A motion record with ``magnet_asymmetry`` named bounds ``cogging`` against the base
    and it; records of the same motor with fresh noise and both, cogging at 1.5x that bound,
    name both, at half of it the first only. With ``max_effects`` named, no bound."""
    seed = 3302
    record = _bench("motion_record")
    d0 = diagnose(record(seed, seed, 1, 0.0)).doc
    bm = next(b for b in d0["detection_bounds"] if b["effect"] == "magnet_asymmetry")
    mo = int(bm["at"].split()[1])
    named = ((mo, 10 * bm["bound"]),)
    d = diagnose(record(seed, seed, 1, 0.0, more=named)).doc
    validate_diagnosis(d)
    assert [e["name"] for e in d["effects"]] == ["magnet_asymmetry"]
    assert d["detection_bounds_reference"]["named"] == ["magnet_asymmetry"]
    # no room for another effect: every bound is null, with the reason
    d1 = diagnose(record(seed, seed, 1, 0.0, more=named), max_effects=1).doc
    validate_diagnosis(d1)
    assert d1["detection_bounds_reference"]["room_for_another_effect"] is False
    assert d1["detection_bounds"]
    assert all(b["bound"] is None and "max_effects" in b["note"] for b in d1["detection_bounds"])
    (b,) = [b for b in d["detection_bounds"] if b["effect"] == "cogging"]
    co = int(b["at"].split()[1])
    got = {}
    for factor, key in ((1.5, seed * 1000), (0.5, seed * 1000 + 500)):
        doc = diagnose(record(seed, key, co, factor * b["bound"], more=named)).doc
        got[factor] = [e["name"] for e in doc["effects"]]
    assert sorted(got[1.5]) == ["cogging", "magnet_asymmetry"], got
    assert got[0.5] == ["magnet_asymmetry"], got


def _runout_record(noise_rad: float):
    """A multihead record (3 heads, theta_ref, 2 runs of 1500 rows at two speeds, disk error
    at orders 1-4) with white noise ``noise_rad`` (the same draws at every level)."""
    from encdesign import Recording

    g = np.random.default_rng([2401, 1])
    alpha = np.radians([0.0, 97.0, 221.0])
    ts, ths, runs = [], [], []
    for r in range(2):
        t = np.arange(1500) / 400.0
        ths.append(2 * np.pi * 6 * (1 + 0.5 * r) * t / t[-1] + g.uniform(0, 6.3))
        ts.append(t + r * (t[-1] + 2))
        runs.append(np.full(1500, r))
    t, th, run = np.concatenate(ts), np.concatenate(ths), np.concatenate(runs)
    err = sum(
        2e-6 / m * np.sin(m * (th[:, None] - alpha[None, :]) + g.uniform(0, 6.3))
        for m in range(1, 5)
    )
    y = th[:, None] + err + noise_rad * g.normal(size=err.shape)
    cols = {"t": t, "run": run, "theta_ref": th} | {f"h{k}": y[:, k] for k in range(3)}
    enc = {
        "head_angles_deg": np.degrees(alpha).tolist(),
        "optical_radius_m": 0.03,
        "grating_lines": 4096,
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


def _bounds_at(doc: dict, effects) -> dict:
    return {(b["effect"], b["where"]): b for b in doc["detection_bounds"] if b["effect"] in effects}


def test_multihead_runout_bounds_grow_with_the_noise():
    """``beam_tilt_axial`` (per head), ``bearing_wobble`` and ``eccentricity_shift`` (one each,
    their order or time held and stated in ``at``) are bounded on a clean multihead record,
    not listed as uncovered; at twice the noise (same draws) each bound about doubles."""
    effects = ("beam_tilt_axial", "bearing_wobble", "eccentricity_shift")
    got = []
    for noise in (1e-7, 2e-7):
        d = diagnose(_runout_record(noise)).doc
        validate_diagnosis(d)
        assert d["verdict"] == "consistent"
        assert not set(effects) & set(d.get("detection_bounds_not_covered", []))
        got.append(_bounds_at(d, effects))
    lo, hi = got
    assert (
        set(lo)
        == set(hi)
        == {
            *(("beam_tilt_axial", h) for h in ("h0", "h1", "h2")),
            ("bearing_wobble", "all"),
            ("eccentricity_shift", "all"),
        }
    )
    assert lo[("bearing_wobble", "all")]["unit"] == "m"
    assert "order" in lo[("bearing_wobble", "all")]["at"]
    for key, b in lo.items():
        assert b["bound"] is not None and 0 < b["bound"] < 1e-3, (key, b)
        assert b["at"], key
        assert 1.5 < hi[key]["bound"] / b["bound"] < 3.0, (key, b["bound"], hi[key]["bound"])


def _sds_noisier(tmp_path, key: int, jitter_s: float, run_offset_s: float):
    """A clean sds bench (8 runs, 3 moving and 2 fixed sensors, phi_ref) with more noise of
    both kinds its levels estimate: ``jitter_s`` more timing noise on every edge (the
    revolution contrasts) and a random delay of ``run_offset_s`` per run and moving sensor
    (the run means), the same draws at every level, stamped on its clock again."""
    from encdesign import Recording

    rec, _ = write_concealed_sds(tmp_path / f"j{key}.toml", key=jax.random.key(key), **GEOM)
    clock = 1.0 / float(rec.meta["encoder"]["clock_hz"])
    t = np.asarray(rec.columns["t"], float)
    g = np.random.default_rng([key, 3])
    run = np.asarray(rec.columns["run"])
    sensor = np.asarray(rec.columns["sensor"])
    moving = np.char.startswith(sensor.astype(str), "m")
    m = np.where(moving, np.char.lstrip(sensor.astype(str), "mf"), "0").astype(int)
    offsets = g.normal(size=(int(run.max()) + 1, int(m.max()) + 1))
    t = t + jitter_s * g.normal(size=t.size) + run_offset_s * offsets[run, m] * moving
    cols = dict(rec.columns) | {"t": np.round(t / clock) * clock}
    meta = {k: v for k, v in rec.meta.items() if k != "data"}
    return Recording("sds", meta, cols)


def test_sds_platform_bounds_grow_with_the_noise(tmp_path):
    """``axis_tilt`` (on ``beta^2 / 4``: a small tilt's error is linear in it),
    ``bearing_wobble``, ``beam_tilt_axial`` and ``coil_mismatch`` are bounded on a clean sds
    bench, not listed as uncovered; with both noise levels (run means, revolution contrasts)
    raised on the same bench each bound grows."""
    effects = ("axis_tilt", "bearing_wobble", "beam_tilt_axial", "coil_mismatch")
    got, lv = [], []
    for jitter, offset in ((0.0, 0.0), (6e-9, 2e-10)):
        d = diagnose(_sds_noisier(tmp_path, 2402, jitter, offset)).doc
        validate_diagnosis(d)
        assert d["verdict"] == "consistent"
        assert not set(effects) & set(d.get("detection_bounds_not_covered", []))
        got.append(_bounds_at(d, effects))
        e = d["noise"]["estimate"]
        lv.append(np.array([e["run_means_rad"], e["contrasts_common_rad"]]))
    lo, hi = got
    assert {e for e, _ in lo} == set(effects) and set(lo) == set(hi)
    assert lo[("axis_tilt", "all")]["parameter"] == "tilt_squared_over_4_rad"
    assert np.all(lv[1] > 1.5 * lv[0]), lv
    for key, b in lo.items():
        assert b["bound"] is not None and 0 < b["bound"] < 1e-5, (key, b)
        assert hi[key]["bound"] > 1.3 * b["bound"], (key, b["bound"], hi[key]["bound"])
    # the worst of several shapes: each one's own bound beside it, the largest the bound
    for name, labels in (
        ("axis_tilt", {f"azimuth {a} deg" for a in ("0", "22.5", "45", "67.5")}),
        ("beam_tilt_axial", {"order 1", "order 2", "order 3"}),
    ):
        each = lo[(name, "all")]["each"]
        assert {e["label"] for e in each} == labels, each
        assert max(e["bound"] for e in each) == lo[(name, "all")]["bound"]
    assert "each" not in lo[("coil_mismatch", "all")]


def test_sds_coil_beside_another_effect(tmp_path):
    """``coil_beside_noise`` puts the generator's own ``coil_mismatch`` beside another effect
    without drawing anything: alone it is the ``coil_mismatch`` record of the same key and
    size, beside an axis tilt it leaves the tilt's draws (platform positions, azimuth) as
    they are, and beside a coil mismatch it is refused."""
    key = jax.random.key(4810)

    def rec(name, **kw):
        return write_concealed_sds(tmp_path / f"{name}.toml", key=key, **dict(GEOM, n_runs=4), **kw)

    coil, t_coil = rec("coil", effect="coil_mismatch", amplitude_noise=3.0)
    beside, t_beside = rec("beside", coil_beside_noise=3.0)
    tilt, t_tilt = rec("tilt", effect="axis_tilt", amplitude_noise=5.0)
    both, t_both = rec("both", effect="axis_tilt", amplitude_noise=5.0, coil_beside_noise=3.0)
    for col in coil.columns:
        np.testing.assert_array_equal(beside.columns[col], coil.columns[col])
    assert t_beside["beside"]["torque_order_1"] == t_coil["params"]["torque_order_1"]
    assert t_both["params"] == t_tilt["params"] and "beside" not in t_tilt
    np.testing.assert_array_equal(both.columns["phi_ref"], tilt.columns["phi_ref"])
    moved = [c for c in tilt.columns if not np.array_equal(both.columns[c], tilt.columns[c])]
    assert moved, "the coil beside the tilt changed no column"
    with pytest.raises(ValueError, match="coil_beside_noise"):
        rec("bad", effect="coil_mismatch", coil_beside_noise=3.0)


class _NoMemo:
    """A chunk memo that keeps nothing."""

    def at(self, a: int) -> None:
        pass

    def get(self, key: tuple):
        return None

    def put(self, key: tuple, value) -> None:
        pass


def test_probes_with_the_same_columns_share_one_jacobian(monkeypatch):
    """Issue 43: in the bounds' one pass over the rows (``_Bench.prepare``), probes whose held
    terms have the same columns (interpolation_error's, one per head) sum one Gram matrix
    (their rank) and evaluate one Jacobian per chunk; every bound is the one of the probes
    prepared one by one, to the last bit. The fitter's Jacobian cache is off, as on a long
    record, where each probe used to evaluate the Jacobian again."""
    import encdesign.diagnose.engine._bounds as bounds
    import encdesign.diagnose.engine._fit as fit

    monkeypatch.setattr(fit, "CACHE_BYTES", 0)
    rec = _vibration_record(1531, 1531, 0.0, 1, None)[0]
    calls: dict[str, int] = {"gram": 0, "jac": 0}
    add_gram, valjac = bounds._add_gram, fit.linear_valjac

    def counted_gram(*a, **k):
        calls["gram"] += 1
        return add_gram(*a, **k)

    def counted_valjac(cand):
        f = valjac(cand)

        def g(*a, **k):
            calls["jac"] += cand.name == "interpolation_error"
            return f(*a, **k)

        return g

    monkeypatch.setattr(bounds, "_add_gram", counted_gram)
    monkeypatch.setattr(fit, "linear_valjac", counted_valjac)
    shared = diagnose(rec).doc
    n_gram, n_jac = calls["gram"], calls["jac"]
    # every probe its own columns and Jacobian: the pass as it was
    monkeypatch.setattr(bounds, "_columns_key", lambda t: (id(t),), raising=False)
    monkeypatch.setattr(bounds, "ChunkMemo", _NoMemo, raising=False)
    calls.update(gram=0, jac=0)
    alone = diagnose(rec).doc
    heads = len(shared["noise"]["channels"])
    assert heads > 1 and shared["detection_bounds"] == alone["detection_bounds"]
    assert calls["gram"] > n_gram and calls["jac"] == heads * n_jac, (calls, n_gram, n_jac)
