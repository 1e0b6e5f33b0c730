"""The finder engine's data pipeline: lazy row columns, chunked passes, progress, Jacobians."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import encdesign  # noqa: F401  (float64)
from encdesign.diagnose.engine._fit import valjac_fn
from encdesign.diagnose.engine._protocol import KeptRows, RowColumns
from encdesign.diagnose.kinds.multihead._multihead import _base_candidate


@pytest.mark.parametrize("all_kept", [True, False])
def test_row_columns_make_the_onehot_and_select_kept_rows(all_kept):
    rng = np.random.default_rng(3)
    n, R = 50, 3
    run = np.sort(rng.integers(0, R, n))
    rows = RowColumns({"t": np.arange(n) * 1e-3, "tau": rng.normal(size=n)}, run, R)
    oh = np.zeros((n, R))
    oh[np.arange(n), run] = 1.0
    assert set(rows) == {"t", "tau", "run_onehot"} and len(rows) == 3
    np.testing.assert_array_equal(rows["run_onehot"], oh)
    np.testing.assert_array_equal(rows.onehot(10, 20), oh[10:20])
    assert "run_onehot" not in dict(rows.stored())
    keep = np.ones(n, bool) if all_kept else rng.uniform(size=n) > 0.3
    kept = KeptRows(rows, keep)
    for k in ("t", "tau", "run_onehot"):
        np.testing.assert_array_equal(kept[k], rows[k][keep])
    full = {k: v for k, v in kept.items()}
    assert set(full) == {"t", "tau", "run_onehot"}
    kept["theta"] = np.zeros(int(keep.sum()))
    assert "theta" in kept and kept["theta"].shape == (int(keep.sum()),)


def test_base_term_jacobian_matches_central_differences_across_runs():
    """The jitted value-and-Jacobian of the base term (every parameter, nonlinear run offsets
    and placements included) against central differences at a point with a disk error:
    an earlier split of the Jacobian into linear / nonlinear halves returned zero rows here."""
    rng = np.random.default_rng(0)
    # the engine's chunk (8192 rows), 4 heads, 4 runs (the last absent from this chunk), 12
    # orders: the shape on which the split Jacobian went wrong
    n, C, R, M = 8192, 4, 4, 12
    run = np.minimum(np.arange(n) // 4000, 2)
    oh = np.zeros((n, R))
    oh[np.arange(n), run] = 1.0
    x = {
        "theta_raw": np.sort(rng.uniform(0, 40, n)),
        "run_onehot": oh,
        "alpha": np.array([0.0, 2.1, 4.2, 0.9]),
    }
    p = {
        "offset_rad": rng.normal(0, 1e-6, (R, C)),
        "fourier_cos_rad": rng.normal(0, 4e-6, M),
        "fourier_sin_rad": rng.normal(0, 4e-6, M),
        "placement_rad": rng.normal(0, 1e-3, C - 1),
        "run_angle_offset_rad": rng.normal(0, 0.5, R - 1),
    }
    cand = _base_candidate(C, R, M)
    pj = {k: jnp.asarray(v) for k, v in p.items()}
    v, J = valjac_fn(cand)(pj, x)
    np.testing.assert_allclose(np.asarray(v), np.asarray(cand.fn(pj, x)), rtol=0, atol=1e-18)
    h = 1e-6
    for name in ("run_angle_offset_rad", "placement_rad"):
        Jn = np.asarray(J[name]).reshape(n, C, -1)
        for j in range(p[name].size):
            d = np.zeros(p[name].size)
            d[j] = h
            up = {**pj, name: jnp.asarray(p[name] + d.reshape(p[name].shape))}
            dn = {**pj, name: jnp.asarray(p[name] - d.reshape(p[name].shape))}
            fd = (np.asarray(cand.fn(up, x)) - np.asarray(cand.fn(dn, x))) / (2 * h)
            scale = max(np.max(np.abs(fd)), 1e-300)
            assert np.max(np.abs(Jn[:, :, j] - fd)) <= 1e-5 * scale + 1e-14, (name, j)


def _bench(n_per_run: int, heads: int, ref: bool, shuffle: bool = False, seed: int = 0):
    """A small multihead recording (per-run zeros, two speeds, 0.5 urad noise)."""
    from encdesign import Recording

    rng = np.random.default_rng(seed)
    cols: dict[str, list] = {"t": [], "run": [], "theta_ref": []}
    alpha = np.array([0.0, 2.1, 4.2, 0.9][:heads])
    for k in range(heads):
        cols[f"h{k}"] = []
    for r in range(3):
        t = np.arange(n_per_run) / 1000.0
        th = 2 * np.pi * (0.7 + 0.5 * r) * t + rng.uniform(0, 6)
        cols["t"].append(t)
        cols["run"].append(np.full(n_per_run, 7 * r + 2))
        cols["theta_ref"].append(th + rng.uniform(-3, 3))
        for k in range(heads):
            e = 3e-6 * np.sin(2 * (th - alpha[k])) + rng.normal(0, 0.5e-6, th.size)
            cols[f"h{k}"].append(th + e + rng.uniform(-3, 3))
    cols = {k: np.concatenate(v) for k, v in cols.items()}
    if not ref:
        del cols["theta_ref"]
    if shuffle:
        p = rng.permutation(cols["t"].size)
        cols = {k: v[p] for k, v in cols.items()}
    enc = {"optical_radius_m": 0.02, "head_angles_deg": np.degrees(alpha).tolist()}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


@pytest.mark.parametrize("ref", [True, False])
def test_prepared_record_holds_little_per_row_and_lazy_columns_are_exact(ref):
    """Bounded memory: a prepared multihead record owns only ``y`` (8 B a channel) and its
    small indices per row (and the heads' mean without a reference); every other row column is
    the recording's own array or
    lazy, and a lazy column read per chunk equals the whole column."""
    from encdesign.diagnose.engine._prepare import prepare
    from encdesign.diagnose.kinds.multihead._multihead import multihead_data

    rec = _bench(2000, 3, ref)
    kd = multihead_data(rec)
    prep = prepare(kd, dict(rec.meta))
    n, C = prep.n, prep.n_channels
    rec_ids = {
        id(np.asarray(v).base if np.asarray(v).base is not None else v)
        for v in rec.columns.values()
    }
    owned = [prep.y, prep.kd.y, prep.kd.shaft, prep.keep, prep.fold, prep.seg, prep.run]
    owned += [v for _, v in prep.rows.stored()]
    seen, per_row = set(), 0.0
    for a in owned:
        root = a.base if a.base is not None else a
        if id(root) in seen or id(root) in rec_ids or a.strides == (0,) * a.ndim:
            continue
        seen.add(id(root))
        per_row += a.nbytes / n
    # y, the run and segment indices, keep and fold; without a reference the shaft angle
    # (the heads' mean) too
    assert per_row <= 8 * C + 4 + 4 + 1 + 1 + (0 if ref else 8) + 1e-9, per_row
    # lazy columns: chunk reads agree with whole reads (and with their definitions)
    for k in ("tau", "omega", "direction", "driver", "psi", "reading"):
        whole = np.asarray(prep.rows[k])
        parts = np.concatenate([prep.rows.column(k, a, min(n, a + 777)) for a in range(0, n, 777)])
        np.testing.assert_array_equal(parts, whole)
        idx = np.array([5, n - 1, 17, 17, 1200])  # any rows, any order: the span is computed
        np.testing.assert_array_equal(prep.rows.take(k, idx), whole[idx])
        np.testing.assert_array_equal(prep.rows.take(k, 33), whole[33])
    for h, col in enumerate(rec.head_columns):
        np.testing.assert_array_equal(prep.rows["reading"][:, h], rec.columns[col])
    t, run = prep.rows["t"], prep.run
    for r in range(3):
        m = run == r
        assert np.all(np.diff(prep.rows["tau"][m]) > 0)
        om = prep.rows["omega"][m & prep.keep]
        np.testing.assert_allclose(om, 2 * np.pi * (0.7 + 0.5 * r), rtol=1e-6)
    assert np.all(np.diff(prep.rows["tau"]) > 0)  # runs follow one another in time
    del t


def test_shuffled_rows_give_the_same_diagnosis():
    """Rows in any order: the record is sorted run by run in time (a copy is made only then)
    and diagnosed as the sorted one."""
    from encdesign.diagnose._dispatch import diagnose

    a = diagnose(_bench(600, 2, True), verbose=False).doc
    b = diagnose(_bench(600, 2, True, shuffle=True), verbose=False).doc
    assert a["verdict"] == b["verdict"]
    np.testing.assert_allclose(b["rms_before"], a["rms_before"], rtol=1e-9)
    np.testing.assert_allclose(b["noise"]["per_channel"], a["noise"]["per_channel"], rtol=1e-9)


@pytest.mark.parametrize(
    ("spr", "revs", "limit"),
    [(10.0, 20.0, 4), (10.37, 20.0, 40), (10.37, 3.0, 15), (200.0, 0.5, 1)],
)
def test_coverage_resolves_orders_above_the_per_revolution_nyquist(spr, revs, limit):
    """A whole number of samples per revolution aliases order spr/2 onto lower ones;
    many revolutions at a rate that is not one fill the circle (all orders to 40 resolved);
    half a turn cannot tell order 2 from order 1 and a constant."""
    from encdesign.diagnose.kinds.multihead._multihead import coverage_limit

    n = int(spr * revs)
    th = np.arange(n) * 2 * np.pi / spr + 0.3
    from encdesign.diagnose import DEFAULT_SETTINGS

    got = coverage_limit(th, np.zeros(n, int), 1, 40, coverage_min=DEFAULT_SETTINGS.coverage_min)
    assert got == limit


def _clean_bench(seed, heads, ref, n_run, turns, rate_hz, orders, amp_over_noise, noise):
    """A clean encoder (one disk error function of ``orders`` orders seen through every head,
    per-run zeros, two runs at two speeds), as an independent program would write it."""
    from encdesign import Recording

    rng = np.random.default_rng(seed)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.3, 6.0, heads - 1))])
    ts, ths, runs = [], [], []
    for r in range(2):
        t = np.arange(n_run) / rate_hz
        ths.append((1 + 0.4 * r) * turns * 2 * np.pi * t / t[-1] + rng.uniform(0, 6))
        ts.append(t + r * (t[-1] + 1.0))
        runs.append(np.full(n_run, r))
    t, th, run = map(np.concatenate, (ts, ths, runs))
    y = np.repeat(th[:, None], heads, 1)
    for m in range(1, orders + 1):
        a, ph = amp_over_noise * noise / m, rng.uniform(0, 6.3)
        y += a * np.sin(m * (th[:, None] - alpha[None, :]) + ph)
    y += rng.normal(0, noise, y.shape) + rng.uniform(-3, 3, (2, heads))[run]
    cols = {"t": t, "run": run, **{f"h{k}": y[:, k] for k in range(heads)}}
    if ref:
        cols["theta_ref"] = th + rng.uniform(-3, 3, 2)[run]
    enc = {"head_angles_deg": np.degrees(alpha).tolist(), "optical_radius_m": 0.02}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


@pytest.mark.parametrize(
    ("case", "kw"),
    [
        # 12.4 samples per revolution, 40-56 turns, disk orders to 9: orders above the
        # per-revolution Nyquist limit (5) are resolved by the many revolutions together
        ("sparse", dict(heads=2, ref=True, n_run=600, turns=40.0, rate_hz=300.0, orders=9)),
        # no theta_ref and a disk error of 300x the noise: the heads' mean reading carries the
        # error's head mean, and the error at that angle has second-order harmonics
        ("large", dict(heads=3, ref=False, n_run=1500, turns=8.0, rate_hz=300.0, orders=6)),
        # a disk error with orders to 18 (above the default base order 12): they join the base
        ("high", dict(heads=3, ref=True, n_run=1500, turns=5.0, rate_hz=300.0, orders=18)),
    ],
)
def test_clean_benches_beyond_the_simple_regime_are_consistent(case, kw):
    from encdesign.diagnose import diagnose

    amp = 300.0 if case == "large" else 30.0
    d = diagnose(_clean_bench(11, amp_over_noise=amp, noise=2e-5, **kw)).doc
    assert d["verdict"] == "consistent", d["report"]
    if case == "large":
        assert "heads' mean reading" in d["base"]["refined"]
    elif case == "high":
        assert set(range(13, 19)) <= set(d["base"]["grown_orders"]), d["base"]
    else:
        assert d["base"]["max_order"] >= 9


def test_clean_motor_with_a_slow_speed_wander_is_consistent():
    """A motor at 10 turns whose speed loop wanders by 0.1 % over the record (0.3 cycle, an
    angle excursion 2,000x the noise): slower than the revolutions, it is base (the drift
    polynomial's degree grows with the turns; a cubic left it as structure)."""
    from encdesign import Recording
    from encdesign.diagnose import diagnose

    rng = np.random.default_rng(5)
    t = np.arange(10000) / 2000.0
    w = 10 * 2 * np.pi / t[-1]
    f = 0.3 / t[-1]
    th = w * t + 0.001 * w / (2 * np.pi * f) * np.sin(2 * np.pi * f * t + 1.0)
    th += rng.normal(0, 1.5e-5, t.size)
    meta = {
        "format": "encdesign-recording/1",
        "kind": "motion",
        "motor": {"pole_pairs": 11, "stator_slots": 24},
    }
    d = diagnose(Recording("motion", meta, {"t": t, "theta": th})).doc
    assert d["verdict"] == "consistent", d["report"]
    assert d["base"]["drift_degree"] == 5


def test_a_quantized_reading_is_not_read_as_glitches_or_count_jumps():
    """Second differences of a reading on a lattice (LSB = 4 sigma) are mostly exactly 0:
    their MAD is 0, and before every step of the staircase read as a glitch or a count
    jump (595 on a concealed bench). The trimmed-RMS scale sees the lattice; a real glitch
    of 60 sigma is still found."""
    from encdesign.diagnose.engine._prepare import find_glitches, robust_scale

    rng = np.random.default_rng(4)
    n, sigma = 3000, 1e-4
    t = np.arange(n) * 5e-3
    x = 0.3 * t + 2e-3 * np.sin(2 * np.pi * 0.2 * t)
    q = 4 * sigma
    y = np.round((x + rng.normal(0, sigma, n)) / q) * q - 0.3 * t
    y[1700] += 60 * sigma
    glitches, jumps = find_glitches(y[:, None], np.zeros(n, int), False, t)
    assert [g[0] for g in glitches] == [1700] and jumps == []
    # Gaussian noise: the scale is sigma (the MAD and the trimmed RMS agree)
    z = rng.normal(0, 1.0, (20000, 1))
    assert robust_scale(z)[0] == pytest.approx(1.0, rel=0.03)


def test_three_motor_effects_at_once_are_all_named():
    """Coil mismatch, magnet asymmetry and cogging on one 7-pole-pair, 12-slot motor: each
    candidate alone leaves the others' orders in the views they share, which is not
    structure it only dents (the signature rule counts the orders it touches)."""
    from encdesign.diagnose import diagnose
    from encdesign.simulate import simulate_plan as simulate

    plan = {
        "kind": "motion",
        "case": "compound",
        "effects": ["coil_mismatch", "cogging", "magnet_asymmetry"],
        "per_run_zeros": False,
        "transient": False,
        "glitches": 0,
        "n_runs": 1,
        "turns": 2.0,
        "amplitude": 1.0,
    }
    rec, truth = simulate(np.random.default_rng(7), plan)
    d = diagnose(rec).doc
    assert sorted(e["name"] for e in d["effects"]) == sorted(truth["effects"]), d["report"]


def test_settings_table_in_the_docs_is_generated_from_the_settings():
    """``docs/diagnose.md``'s threshold table is ``settings_table()`` verbatim."""
    import re
    from pathlib import Path

    from encdesign.diagnose import FinderSettings, settings_table

    text = (Path(__file__).resolve().parent.parent / "docs" / "diagnose.md").read_text()
    m = re.search(r"<!-- settings-table -->\n(.*?)<!-- /settings-table -->", text, re.S)
    assert m is not None, "docs/diagnose.md has no settings-table markers"
    assert m.group(1) == settings_table(), "regenerate the table: settings_table()"
    # every field is documented, and a changed default would change the table
    rows = [r for r in settings_table().splitlines() if r.startswith("| `")]
    assert len(rows) == len(FinderSettings.__dataclass_fields__)
    assert all(r.rstrip(" |").split("|")[-1].strip() for r in rows)
    assert settings_table(FinderSettings(bic_min=20.0)) != settings_table()


def test_finder_settings_invariants():
    from encdesign.diagnose import FinderSettings

    with pytest.raises(ValueError, match="bic_min"):
        FinderSettings(bic_min=-1.0)
    with pytest.raises(ValueError, match="n_folds"):
        FinderSettings(n_folds=1)
    assert FinderSettings(discover_max_aliases=0).discover_max_aliases == 0  # a search off
    with pytest.raises(ValueError, match="discover_max_aliases.*integer >= 0"):
        FinderSettings(discover_max_aliases=-1)
    with pytest.raises(ValueError, match="discover_max_aliases"):
        FinderSettings(discover_max_aliases=2.5)


def test_settings_change_the_decision_and_a_refusal_names_its_rule():
    """A generated motor record with cogging: named with the default settings; with a
    criterion no effect can meet it is refused, the refusal names ``bic_min``, and the
    verdict (decided once, after the kind's additions) is not ``missing_physics``."""
    from encdesign.diagnose import FinderSettings, diagnose
    from encdesign.simulate import simulate_plan as simulate
    from tests.helpers import validate_diagnosis

    plan = {
        "kind": "motion",
        "case": "single",
        "effects": ["cogging"],
        "per_run_zeros": False,
        "transient": False,
        "glitches": 0,
        "n_runs": 1,
        "turns": 2.0,
        "amplitude": 1.0,
    }
    rec, truth = simulate(np.random.default_rng(11), plan)
    d0 = diagnose(rec).doc
    assert [e["name"] for e in d0["effects"]] == ["cogging"], d0["report"]
    assert d0["settings"]["bic_min"] == FinderSettings().bic_min
    d1 = diagnose(rec, settings=FinderSettings(bic_min=1e12)).doc
    validate_diagnosis(d1)
    assert not any(e["name"] == "cogging" for e in d1["effects"]), d1["report"]
    refused = [r for r in d1["rejected"] if r["name"] == "cogging"]
    assert refused and "bic_min" in refused[0]["rules"], d1["rejected"]
    assert d1["verdict"] != "missing_physics" or d1["effects"]
    assert d1["verdict"] in d1["report"]


def test_slow_wobble_is_named_when_two_speeds_show_one_order():
    """Issue 22's example: a wobble at order 0.4 gives fewer than 3 cycles in every run;
    runs at different speeds show one order (not one frequency), so the record tells it
    from a slow drift: named, nothing unexplained (it was refused, "could be a slow
    drift", and the record came back unexplained)."""
    from encdesign.diagnose import diagnose
    from tests.helpers import slow_wobble_bench, validate_diagnosis

    d = diagnose(slow_wobble_bench()).doc
    validate_diagnosis(d)
    assert [e["name"] for e in d["effects"]] == ["bearing_wobble"], d["report"]
    nu = d["effects"][0]["params"]["frequency_ratio"]["value"]
    assert abs(nu - 0.4) < 0.02
    assert all(r.get("rule") for r in d["rejected"]), d["rejected"]


@pytest.mark.parametrize(
    "speeds, revs, refused",
    [
        ((1.0, 1.0), (3.0, 3.0), True),  # one speed: a drift in time could pose as it
        ((1.0, 2.0), (3.0, 6.0), False),  # two speeds, 3.6 cycles in all: an order
        ((1.0, 2.0), (1.0, 2.0), True),  # two speeds but 1.2 cycles in all
    ],
)
def test_wobble_rule_needs_few_cycles_only_at_two_speeds(speeds, revs, refused):
    from types import SimpleNamespace

    from encdesign.diagnose import FinderSettings
    from encdesign.diagnose.kinds.multihead._multihead_terms import _wb_plausible

    omega = np.concatenate([np.full(10, 2 * np.pi * s) for s in speeds])
    ctx = SimpleNamespace(
        settings=FinderSettings(), revolutions=np.asarray(revs), rows={"omega": omega}
    )
    why = _wb_plausible(ctx, {"frequency_ratio": np.asarray(0.4)})
    assert (why is not None) == refused, why
    # the thresholds are the settings' (a stricter cycle count refuses the two-speed case)
    strict = SimpleNamespace(**{**vars(ctx), "settings": FinderSettings(wobble_cycles_min=9.0)})
    assert _wb_plausible(strict, {"frequency_ratio": np.asarray(0.4)}) is not None
