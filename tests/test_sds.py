"""Shifted-delta-sum timing model: motor, marks, edge times, SDS, error physics, recordings."""

import math
import re
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SDS_TEST_MARKS, sds_reference

import encdesign as ed
from encdesign._errors import EncdesignInputError
from encdesign.physics._sds_errors import ARCSEC

N = SDS_TEST_MARKS  # marks per revolution (the physics does not depend on N here)
MAS = ARCSEC / 1000

phi_error = jax.jit(ed.sds_phi_error)


def _rough_disk(key, n=N):
    """A disk with large mark errors of every kind (monotone marks)."""
    return ed.physics.reference_disk(
        key, n, eccentricity_rad=1.5e-3, ellipticity_rad=8e-4, harmonic_rad=1e-4, random_rad=2e-4
    )


def _design(motor, n_fixed=2, n_moving=3, key=0, n=N, fixed=None, moving=None):
    ka, kb = jax.random.split(jax.random.PRNGKey(key))
    return ed.SDSDesign(
        motor,
        _rough_disk(ka, n),
        _rough_disk(kb, n),
        ed.physics.equally_spaced(n_fixed, 0.3) if fixed is None else fixed,
        ed.physics.equally_spaced(n_moving, 1.1) if moving is None else moving,
    )


PHI = jnp.asarray([0.0, 0.7, 1.9, 3.0, 3.3, 4.4, 5.9])

# one compiled simulator for every error-physics test: same design and error shapes
simulate = jax.jit(ed.simulate_readings, static_argnums=(2,), static_argnames=("revs_per_reading",))
KEY = jax.random.PRNGKey(0)


def _errs(**kw) -> ed.SDSErrors:
    """SDSErrors with the canonical array shapes of these tests (shared compiles)."""
    base = dict(
        axial_runout_cos_m=[0.0],
        axial_runout_sin_m=[0.0],
        bearing_amplitude_m=np.zeros(6),
        bearing_ratio=np.ones(6),
        bearing_phase_rad=np.zeros(6),
    )
    base.update(kw)
    return ed.SDSErrors(**base)


def _still(n_sensors=1):
    """Constant speed, perfect disks, n equally spaced sensors per disk."""
    motor = ed.Motor(6, 18, 6)
    az = ed.physics.equally_spaced(n_sensors)
    return ed.SDSDesign(motor, ed.physics.perfect_disk(N), ed.physics.perfect_disk(N), az, az)


# ----------------------------------------------------------------------------- motor


def test_motor_orders_follow_construction():
    src = ed.physics.motor_order_sources(6, 18, 6)
    assert set(range(1, 7)) <= set(src)
    assert "cogging" in src[36] and "commutation" in src[36]  # lcm(12, 18) = 36 = 6·6
    assert "pole_pairs" in src[12]
    assert 7 not in src and 13 not in src
    assert ed.physics.motor_orders(5, 15, 6, max_order=40) == (
        1,
        2,
        3,
        4,
        5,
        10,
        15,
        20,
        25,
        30,
        35,
        40,
    )
    with pytest.raises(EncdesignInputError, match="pole_pairs"):
        ed.physics.motor_orders(0, 15, 6)


def test_inertia_filter_and_speed_integral():
    m = ed.Motor(5, 15, 6, torque_cos={5: 0.01, 30: 0.01}, corner_order=3.0)
    c, s = m.speed_ripple()
    amp = dict(zip(m.orders, np.hypot(c, s)))
    assert amp[5] == pytest.approx(0.01 / math.hypot(1, 5 / 3))
    assert amp[30] == pytest.approx(0.01 / math.hypot(1, 10))
    t = jnp.linspace(0.0, 0.3, 2001)
    theta, omega = jax.jit(lambda m: (m.theta(t), m.omega(t)))(m)
    # θ is the integral of ω (trapezoid on a fine grid)
    steps = 0.5 * (omega[1:] + omega[:-1]) * jnp.diff(t)
    integral = jnp.concatenate([jnp.zeros(1), jnp.cumsum(steps)])
    assert float(jnp.max(jnp.abs(theta - integral))) < 1e-6
    # dense copy = same motion
    theta_dense = jax.jit(lambda m: m.theta(t))(m.as_dense())
    assert float(jnp.max(jnp.abs(theta_dense - theta))) < 1e-13
    with pytest.raises(EncdesignInputError, match="not produced"):
        ed.Motor(5, 15, 6, torque_cos={7: 0.01})


def test_edge_times_invert_theta_below_a_picosecond():
    m = ed.physics.reference_motor(6)
    m = eqx.tree_at(lambda x: x.speed_drift_per_s, m, jnp.asarray(2e-4))
    target = jnp.linspace(0.0, 2 * math.pi * 1000, 20001) + 0.123
    t = jax.jit(ed.physics.time_at_angle)(m, target)
    # residual in time: angle residual / speed, over 1,000 revolutions
    dt = (m.theta(t) - target) / m.omega(t)
    assert float(jnp.max(jnp.abs(dt))) < 1e-13


# ----------------------------------------------------------------------------- SDS core


def test_constant_speed_is_exact_for_any_mark_errors():
    motor = ed.Motor(6, 18, 6, speed_rad_s=2 * math.pi * 7.3)
    for key in (0, 1):
        d = _design(motor, 2, 3, key=key)
        ed.physics.validate_design(d)
        err = phi_error(d, PHI)
        assert float(jnp.max(jnp.abs(err))) < 1e-12


def test_k_shift_identity_from_edge_times():
    """S_k(0) = S_0(0) − k·2π for every shift k (seed eq. 11), measured with times."""
    motor = ed.Motor(6, 18, 6)
    d = _design(motor, 1, 1, fixed=[0.0], moving=[0.0])
    mu_a = np.asarray(ed.physics.mark_angles(d.disk_a))
    mu_b = np.asarray(ed.physics.mark_angles(d.disk_b))
    s00 = float(np.sum(mu_b - mu_a))  # S_0(0) = Σ (B_i − A_i)
    om = float(motor.speed_rad_s)
    alpha = mu_a / om  # the fixed window starts at A_0 (position 0)
    period = 2 * np.pi / om
    b_ext = np.concatenate([mu_b - 2 * np.pi, mu_b, mu_b + 2 * np.pi])  # B_j, j = −N … 2N−1
    for k in (0, 1, 2, 17, N // 2, N - 1):
        # window of N consecutive B edges that starts k marks before mark 0
        tau_seq = b_ext[N - k : 2 * N - k] / om
        s_k = 2 * np.pi * np.sum(tau_seq - alpha) / period
        assert s_k == pytest.approx(s00 - 2 * np.pi * k, abs=1e-9)
        pos0 = int(np.flatnonzero(np.isclose(tau_seq, mu_b[0] / om))[0])
        assert pos0 == k
        # the pipeline (eq. 23) gives φ = 0 from this window for every k
        by_mark = np.empty(N)
        by_mark[(np.arange(N) - k) % N] = tau_seq
        phi = ed.sds_from_edges(
            alpha[None], [period], [0], by_mark[None], [k], d.zero_offsets_rad()
        )
        assert abs(float(phi[0, 0])) < 1e-12


def test_axis_tilt_matches_seed_formula():
    d = _still()
    tilt = 20 * ARCSEC
    phi = jnp.linspace(0, 2 * math.pi, 49)[:-1]
    err = phi_error(d, phi, _errs(axis_tilt_rad=tilt))
    expect = ed.physics.axis_tilt_error(phi, tilt)
    assert float(jnp.max(jnp.abs(err - expect))) < 1e-15
    assert 0.4 * MAS < float(jnp.max(jnp.abs(err))) < 0.5 * MAS
    # nearly pure order 2 of amplitude β²/4
    spec = np.abs(np.fft.rfft(np.asarray(err))) * 2 / len(phi)
    assert spec[2] == pytest.approx(tilt**2 / 4, rel=1e-3)
    assert spec[2] > 100 * (spec[1] + spec[3] + spec[4])


def test_prediction_eq46_53_agrees_with_simulation():
    d = sds_reference(1, 1)
    phi = jnp.linspace(0, 2 * math.pi, 25)[:-1]
    sim = phi_error(d, phi)
    pred = ed.physics.predict_speed_mark_error(d, phi)
    assert float(jnp.max(jnp.abs(sim))) > 1 * ARCSEC  # a real effect, not zero vs zero
    assert float(jnp.max(jnp.abs(sim - pred.phi_error_rad))) < 0.05 * float(jnp.max(jnp.abs(sim)))
    # the Fourier split sums to the total and is dominated by orders 1 and 2
    tot = jnp.sum(pred.order_error_rad, axis=-1)
    assert float(jnp.max(jnp.abs(tot - pred.phi_error_rad))) < 1e-12
    share = jnp.sum(jnp.abs(pred.order_error_rad[:, 1:3]), -1) / jnp.sum(
        jnp.abs(pred.order_error_rad[:, 1:]), -1
    )
    assert float(jnp.min(share)) > 0.8


def test_sensor_count_cancels_orders():
    """Three equally spaced moving sensors: speed ripple and mark error at order 2 leave a
    constant error (no φ dependence); at order 3 (a multiple of 3) the error varies."""
    phi = jnp.linspace(0, 2 * math.pi, 13)[:-1]
    spread = {}
    for order in (2, 3):
        motor = ed.Motor(3, 9, 6, torque_cos={order: 0.02})
        harm = jnp.zeros(3).at[order - 1].set(5e-4)
        disk = ed.DiskMarks(N, harm, jnp.zeros(3), jnp.zeros(N))
        d = ed.SDSDesign(motor, disk, disk, [0.0], ed.physics.equally_spaced(3))
        e = phi_error(d, phi)
        spread[order] = float(jnp.max(e) - jnp.min(e))
    assert spread[3] > 1e-7
    assert spread[2] < 1e-4 * spread[3]


# ----------------------------------------------------------------------------- gradients


def test_gradients_match_finite_differences():
    d = sds_reference(2, 2)
    phi = jnp.asarray([0.4, 1.3, 2.2, 5.0])

    def obj(tc, hc, rnd):
        m = eqx.tree_at(lambda x: x.motor.torque_cos, d, tc)
        m = eqx.tree_at(lambda x: x.disk_b.harmonic_cos_rad, m, hc)
        m = eqx.tree_at(lambda x: x.disk_a.random_rad, m, rnd)
        e = ed.sds_phi_error(m, phi)
        return jnp.sum(e * jnp.asarray([1.0, -2.0, 0.5, 1.5])) / ARCSEC

    args = (d.motor.torque_cos, d.disk_b.harmonic_cos_rad, d.disk_a.random_rad)
    f = jax.jit(obj)
    grads = jax.jit(jax.grad(obj, argnums=(0, 1, 2)))(*args)
    checks = [(0, 0, 1e-4), (0, 1, 1e-4), (0, 5, 1e-4), (1, 0, 1e-4), (1, 1, 1e-4), (2, 7, 1e-4)]
    for a, i, h in checks:
        plus = list(args)
        minus = list(args)
        plus[a] = args[a].at[i].add(h)
        minus[a] = args[a].at[i].add(-h)
        fd = (f(*plus) - f(*minus)) / (2 * h)
        g = float(grads[a][i])
        assert g == pytest.approx(float(fd), rel=1e-4, abs=1e-5)
    assert abs(float(grads[0][1])) > 1.0  # order-2 ripple matters with two opposed pairs


def test_residual_objective_is_differentiable():
    d = sds_reference(1, 1)
    val, g = jax.jit(jax.value_and_grad(lambda m: ed.physics.sds_residual(m, n_phi=4)))(d)
    assert float(val) > 0
    for leaf in jax.tree_util.tree_leaves(g):  # ripple, marks, azimuths, radius, speed
        assert np.all(np.isfinite(np.asarray(leaf)))
    assert float(jnp.max(jnp.abs(g.motor.torque_cos))) > 0
    assert float(jnp.max(jnp.abs(g.disk_b.harmonic_cos_rad))) > 0


# ----------------------------------------------------------------------------- error physics


def test_bearing_wobble_cancels_in_opposed_pairs_and_noise_averages():
    errs = _errs(**ed.physics.bearing_noise(jax.random.PRNGKey(1), 2.5e-6, 6))
    std = {}
    for n in (1, 2):
        r = simulate(_still(n), 0.5, 8, errs, key=KEY, revs_per_reading=2)
        std[n] = float(jnp.std(r.pair_error_rad.mean(axis=(1, 2))))
    assert std[1] > 1e-3 * ARCSEC
    assert std[2] < 1e-3 * std[1]  # seed: 0.42 → 0.02 arcsec


def test_timing_quantization_and_jitter_are_random_and_average_down():
    d = _still()
    r = simulate(d, 1.0, 8, _errs(clock_period_s=1e-8, jitter_s=3e-9), key=KEY, revs_per_reading=2)
    e = np.asarray(r.pair_error_rad).reshape(-1)
    assert np.all(np.isfinite(e)) and np.std(e) > 0
    # per edge ~ 2π·(σ/T)/√N per sensor; a reading is far below one clock tick
    tick = 2 * math.pi * 1e-8 / float(d.motor.period_s)
    assert np.max(np.abs(e)) < tick
    assert r.error_rad.shape == (4,)
    np.testing.assert_allclose(r.error_rad, e.reshape(4, 2).mean(1), atol=1e-15)
    # without jitter and clock the same simulation is exact
    r0 = simulate(d, 1.0, 8, _errs(), key=KEY, revs_per_reading=2)
    assert float(jnp.max(jnp.abs(r0.pair_error_rad))) < 1e-13


def test_thermal_drift_and_axial_shift():
    d = _still()
    rate = 1.0  # K/s (exaggerated to see it in a few revolutions)
    errs = _errs(thermal_drift_rad_per_k=0.7 * ARCSEC, temperature_rate_k_per_s=rate)
    r = simulate(d, 0.2, 8, errs, key=KEY, revs_per_reading=2)
    per_rev = np.asarray(r.pair_error_rad).reshape(-1)
    slope = np.polyfit(np.arange(8) * float(d.motor.period_s), per_rev, 1)[0]
    assert slope == pytest.approx(0.7 * ARCSEC * rate, rel=1e-3)
    # ΔT = offset + rate t (issue 44, session 22: the offset was left out, so a ramp from t0,
    # offset = -rate t0, jumped by κ rate t0 at its onset): the offset moves the moving
    # sensors by κ offset
    off = -0.1  # K
    errs = _errs(
        thermal_drift_rad_per_k=0.7 * ARCSEC,
        temperature_rate_k_per_s=rate,
        temperature_offset_k=off,
    )
    r_off = simulate(d, 0.2, 8, errs, key=KEY, revs_per_reading=2)
    shift = np.asarray(r_off.pair_error_rad).reshape(-1) - per_rev
    np.testing.assert_allclose(shift, 0.7 * ARCSEC * off, rtol=1e-3)
    # axial runout (order 1 in φ) seen through a tilted optical axis: γ·dz/R
    errs = _errs(optical_tilt_moving_rad=0.01, axial_runout_cos_m=[2e-6])
    phi = jnp.asarray([0.0, math.pi / 2, math.pi])
    e = phi_error(d, phi, errs)
    np.testing.assert_allclose(np.asarray(e), 0.01 * 2e-6 / 0.0254 * np.cos(phi), atol=1e-15)


# ----------------------------------------------------------------------------- recordings


def test_reference_errors_systematic_only():
    """``systematic_only`` is the studies' "no random or time-varying terms" call, field for
    field; keywords still override it, and the full set keeps its noise."""
    explicit = ed.reference_errors(
        bearing_amplitude_m=[],
        bearing_ratio=[],
        bearing_phase_rad=[],
        temperature_rate_k_per_s=0.0,
        clock_period_s=0.0,
        jitter_s=0.0,
    )
    quiet = ed.reference_errors(systematic_only=True)
    a, b = jax.tree.leaves(explicit), jax.tree.leaves(quiet)
    assert jax.tree.structure(explicit) == jax.tree.structure(quiet)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert float(quiet.axis_tilt_rad) > 0 and float(quiet.thermal_drift_rad_per_k) > 0
    assert float(ed.reference_errors(systematic_only=True, jitter_s=2e-9).jitter_s) == 2e-9
    full = ed.reference_errors()
    assert float(full.jitter_s) > 0 and np.size(full.bearing_amplitude_m) > 0


def test_recording_round_trip(tmp_path):
    d = sds_reference(2, 3)
    phis = np.asarray([0.0, 1.0, 2.5, 4.0])
    rec = ed.simulate_sds_recording(tmp_path / "r.toml", d, phis, 2, compress=True)
    assert rec.n_rows == 4 * 3 * N * 5
    loaded = ed.load_recording(tmp_path / "r.toml")
    res = ed.sds_readings_from_recording(loaded)
    sim = np.asarray(phi_error(d, jnp.asarray(phis)))
    np.testing.assert_allclose(res.error_zeroed_rad, sim - sim[0], atol=1e-11)
    assert res.readings_rad[0].shape == (2,)
    np.testing.assert_allclose(np.cos(res.phi_rad - phis), 1.0, atol=1e-8)


def _small_recording(tmp_path: Path) -> Path:
    d = ed.reference_design(1, 1, marks_per_rev=20)
    ed.simulate_sds_recording(tmp_path / "s.toml", d, [0.5], 1)
    return tmp_path / "s.toml"


def _set_field(lines: list[str], row: int, column: str, value: str) -> list[str]:
    header = lines[0].split(",")
    fields = lines[row].split(",")
    fields[header.index(column)] = value
    return lines[:row] + [",".join(fields)] + lines[row + 1 :]


def _edit_csv(path: Path, fn) -> None:
    lines = path.with_suffix(".csv").read_text().splitlines()
    path.with_suffix(".csv").write_text("\n".join(fn(lines)) + "\n")


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda ls: _set_field(ls, 1, "sensor", "f7"), "not declared"),
        (lambda ls: _set_field(ls, 2, "sensor", "x1"), "not declared"),
        (lambda ls: _set_field(ls, 3, "sensor", "m1"), "not declared"),
        (lambda ls: ls[:10] + ls[11:], "missing"),
        (lambda ls: [ls[0], ls[2], ls[1]] + ls[3:], "backwards|jumps"),
    ],
)
def test_bad_sds_recordings_are_refused(tmp_path, edit, match):
    path = _small_recording(tmp_path)
    _edit_csv(path, edit)
    with pytest.raises(EncdesignInputError, match=match):
        ed.load_recording(path)


def test_mark_out_of_range_and_time_backwards(tmp_path):
    path = _small_recording(tmp_path)
    lines = path.with_suffix(".csv").read_text().splitlines()
    header = lines[0].split(",")
    im, it = header.index("mark"), header.index("t")
    row = lines[5].split(",")
    row[im] = "20"
    _edit_csv(path, lambda ls: ls[:5] + [",".join(row)] + ls[6:])
    with pytest.raises(EncdesignInputError, match=r"line 6, column 'mark'.*out of range"):
        ed.load_recording(path)
    path = _small_recording(tmp_path)
    lines = path.with_suffix(".csv").read_text().splitlines()
    # the same sensor's later edge gets an earlier time
    sensor = lines[3].split(",")[header.index("sensor")]
    j = next(
        i for i in range(4, len(lines)) if lines[i].split(",")[header.index("sensor")] == sensor
    )
    row = lines[j].split(",")
    row[it] = "0.0"
    _edit_csv(path, lambda ls: ls[:j] + [",".join(row)] + ls[j + 1 :])
    with pytest.raises(EncdesignInputError, match="backwards"):
        ed.load_recording(path)


def test_recording_without_complete_revolution_is_refused(tmp_path):
    path = _small_recording(tmp_path)
    # keep only the first 15 edges of every sensor: no complete revolution
    _edit_csv(path, lambda ls: ls[:25])
    rec = ed.load_recording(path)
    with pytest.raises(EncdesignInputError, match="no complete revolution"):
        ed.sds_readings_from_recording(rec)


def test_bad_design_input():
    with pytest.raises(EncdesignInputError, match="torque_cos"):
        ed.Motor(6, 18, 6, torque_cos=jnp.zeros(3))
    rnd = 0.2 * (-1.0) ** jnp.arange(20)  # mark errors larger than half the spacing
    disk = ed.DiskMarks(20, jnp.zeros(1), jnp.zeros(1), rnd)
    d = ed.SDSDesign(ed.Motor(6, 18, 6), disk, disk, [0.0], [0.0])
    with pytest.raises(EncdesignInputError, match="does not follow"):
        ed.physics.validate_design(d)
    with pytest.raises(EncdesignInputError, match="marks_per_rev"):
        ed.SDSDesign(
            ed.Motor(6, 18, 6),
            ed.physics.perfect_disk(20),
            ed.physics.perfect_disk(30),
            [0.0],
            [0.0],
        )


# ----------------------------------------------------------------------------- studies


def _run_study(name: str, tmp_path: Path) -> dict:
    import json

    from encdesign.cli import main

    out = tmp_path / name
    assert (
        main(["study", "run", name, "--quick", "--out", str(out), "--json", str(out / "s.json")])
        == 0
    )
    assert any(out.glob("*.png"))
    return json.loads((out / "s.json").read_text())


def test_study_sds_errors_quick(tmp_path):
    res = _run_study("sds-errors", tmp_path)
    assert 0.4 < res["axis_tilt_20arcsec_max_mas"] < 0.5
    # seed figs. 17–20, 23–24: one pair strong order 1; two opposed pairs no order 1 but
    # order 2; three sensors order 2 strongly reduced
    assert res["single_pair_order1_arcsec"] > 0.5
    assert res["two_pairs_order1_arcsec"] < 1e-6 * res["single_pair_order1_arcsec"]
    assert res["two_pairs_order2_arcsec"] > 0.1
    assert res["three_sensor_order2_arcsec"] < 1e-2 * res["two_pairs_order2_arcsec"]
    assert set(res["budget_two_pairs"]) >= {"axis_tilt", "bearing_wobble", "all"}


def test_study_sds_poles_quick(tmp_path):
    res = _run_study("sds-poles", tmp_path)
    table = np.asarray(res["residual_rms_arcsec"])
    assert table.shape == (10, 4)
    assert len(res["table"]) == 40
    # the seed's rule: 5 pole pairs with 3 sensors beats 6 with 3
    assert res["five_pole_pairs_three_sensors_arcsec"] < res["six_pole_pairs_three_sensors_arcsec"]
    for m in ("sensors_3", "sensors_4"):
        r = res["rule_pole_count_not_multiple_of_sensors"][m]
        assert r["mean_residual_pole_not_multiple_arcsec"] < r["mean_residual_pole_multiple_arcsec"]


def test_cli_sds_simulate_and_measure(tmp_path, capsys):
    from encdesign.cli import main

    rec = tmp_path / "cli.toml"
    args = ["sds", "simulate", "--out", str(rec), "--marks", "20", "--revs", "2"]
    args += ["--fixed", "1", "--moving", "1"]
    assert main(args + ["--phi-deg", "0", "100", "--errors", "none"]) == 0
    assert main(["sds", "measure", str(rec), "--json", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    phi_deg = [float(x) for x in re.findall(r"run +\d+: phi +([-\d.]+) deg", out)]
    np.testing.assert_allclose(phi_deg, [0.0, 100.0], atol=1e-3)
    _edit_csv(rec, lambda ls: _set_field(ls, 4, "mark", "21"))
    assert main(["sds", "measure", str(rec)]) == 2
    assert "out of range" in capsys.readouterr().err


def test_padded_error_models_give_bit_equal_edge_times_in_one_program():
    """``simulate._sds.padded_errors``: zero bearing components and axial orders appended
    change no edge time (bit for bit, with jitter and clock), and a clean run and a wobbling,
    axially tilted one then share one compiled edge-time program. (Three models, three
    unpadded shapes: each shape is a compile of its own.)"""
    from encdesign.physics._sds_errors import SDSErrors
    from encdesign.simulate._conceal_sds import sds_bench_design
    from encdesign.simulate._sds import _edge_times_jit, padded_errors

    design = sds_bench_design(jax.random.key(5), 60, 0.0, 3, 2, 5)
    clock = dict(clock_period_s=1e-8, jitter_s=1e-9)
    models = [
        SDSErrors(**clock),
        SDSErrors(**clock, bearing_amplitude_m=[3e-6], bearing_ratio=[0.41],
                  bearing_phase_rad=[1.0], optical_tilt_moving_rad=0.01,
                  axial_runout_cos_m=[2e-5, 0.0, 1e-5], axial_runout_sin_m=[1e-5, 0.0, -4e-6]),
        # every reference term (2 axial orders), 5 bearing components, a thermal ramp
        ed.physics.reference_errors(thermal_drift_rad_per_k=1e-5, temperature_rate_k_per_s=0.1,
                  temperature_offset_k=-0.2, bearing_amplitude_m=[1e-6] * 5,
                  bearing_ratio=[0.3, 0.4, 0.5, 0.6, 0.7], bearing_phase_rad=[0.0] * 5),
    ]  # fmt: skip
    sizes = set()
    for errors in models:
        padded = padded_errors(errors)
        sizes.add((padded.bearing_amplitude_m.shape, padded.axial_runout_cos_m.shape))
        kw = dict(key=jax.random.key(9), first_rev=jnp.asarray(7.0))
        old = _edge_times_jit(design, jnp.asarray(1.3), 3, errors, **kw)
        new = _edge_times_jit(design, jnp.asarray(1.3), 3, padded, **kw)
        for a, b in zip(old, new, strict=True):
            assert np.array_equal(np.asarray(a), np.asarray(b))
    # the first two (0 and 1 bearing components, 0 and 3 axial orders) pad alike, the
    # last (5 components, 2 orders) to the next bucket
    assert sizes == {((4,), (4,)), ((8,), (4,))}
