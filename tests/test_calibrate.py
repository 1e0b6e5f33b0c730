"""Calibration procedures: dual closure, calibration curves, reference mapping (issue 13)."""

import json
import math

import jax
import numpy as np
import pytest
from helpers import CLOSURE_FACE_RAD, CLOSURE_SIGMA_RAD, closure_instrument_error

from encdesign import EncdesignInputError
from encdesign.calibrate import (
    AccelerometerLevels,
    accelerometer_levels,
    apply_correction_table,
    build_stepped_lut,
    closure_counts,
    closure_from_recording,
    closure_matrix,
    combine_luts,
    compare_maps,
    compare_maps_on_recording,
    curve_from_closure,
    fit_curve,
    mount_relative_displacement_m,
    read_correction_table,
    reference_map,
    solve_closure,
    undetermined_harmonics,
    write_correction_table,
)
from encdesign.cli._main import main
from encdesign.io._closure_recording import write_closure_recording
from encdesign.io._recording import load_recording, write_recording
from encdesign.simulate import simulate_closure_readings, simulate_shaker_steps

ARCSEC = math.pi / (180 * 3600)


def _simulate(n, positions, seed=0, sigma=CLOSURE_SIGMA_RAD):
    rng = np.random.default_rng(seed)
    face = rng.normal(0.0, CLOSURE_FACE_RAD, n)
    off = rng.uniform(-5, 5, len(positions)) * ARCSEC
    readings = simulate_closure_readings(
        closure_instrument_error,
        n,
        positions,
        face_error_rad=face,
        setting_offset_rad=off,
        sigma_reading_rad=sigma,
        key=jax.random.PRNGKey(seed),
    )
    e_true = closure_instrument_error(2 * np.pi * np.arange(n) / n)
    return readings, e_true - e_true.mean(), face - face.mean()


# ----------------------------------------------------------------------------- counts


@pytest.mark.parametrize(
    "n, settings, measurements, equations, unknowns",
    [
        (12, 12, 156, 146, 24),  # seed: complete test, N = 12
        (72, 72, 5256, 5186, 144),  # seed: complete test, N = 72
        (72, 15, 1095, 1082, 144),  # seed: partial test, 15 settings
    ],
)
def test_seed_equation_counts(n, settings, measurements, equations, unknowns):
    c = closure_counts(n, settings)
    assert (c.n_measurements, c.n_equations, c.n_unknowns) == (measurements, equations, unknowns)
    a = closure_matrix(n, list(range(settings)))
    assert a.shape == (equations, unknowns)
    assert np.linalg.matrix_rank(a) == unknowns  # every harmonic determined


def test_solver_reports_the_seed_counts():
    readings, _, _ = _simulate(12, list(range(12)))
    res = solve_closure(readings, list(range(12)))
    assert (res.counts.n_measurements, res.counts.n_equations, res.counts.n_unknowns) == (
        156,
        146,
        24,
    )
    assert res.rank == 24 and res.dof == 146 - 24 and res.status == "ok"


# ----------------------------------------------------------------------------- recovery


@pytest.mark.parametrize(
    "n, positions",
    [(12, list(range(12))), (17, list(range(17))), (72, list(range(15))), (72, [0, 5, 11, 30])],
)
def test_recovery_is_chi2_consistent(n, positions):
    """Recovered errors agree with the truth within the stated covariance (χ² over 8
    draws, two-sided 0.1 % bounds)."""
    chi_e = chi_f = 0.0
    dof_e = dof_f = 0
    for seed in range(8):
        readings, e_true, f_true = _simulate(n, positions, seed=seed)
        res = solve_closure(readings, positions)
        ce, de = res.instrument_chi2(e_true)
        cf, df = res.face_chi2(f_true)
        chi_e, chi_f, dof_e, dof_f = chi_e + ce, chi_f + cf, dof_e + de, dof_f + df
        assert de == n - 1 and df == n - 1
    from scipy.stats import chi2

    for c, d in ((chi_e, dof_e), (chi_f, dof_f)):
        assert 1e-3 < chi2.sf(c, d) < 1 - 1e-3, (c, d)


def test_residual_sigma_estimates_the_noise():
    readings, _, _ = _simulate(72, list(range(23)), sigma=0.02 * ARCSEC)
    res = solve_closure(readings, list(range(23)))
    assert res.sigma_residual_rad == pytest.approx(0.02 * ARCSEC, rel=0.08)


def test_wrong_stated_sigma_shows_in_chi2():
    readings, _, _ = _simulate(12, list(range(12)), sigma=0.02 * ARCSEC)
    ok = solve_closure(readings, list(range(12)), sigma_reading_rad=0.02 * ARCSEC)
    bad = solve_closure(readings, list(range(12)), sigma_reading_rad=0.005 * ARCSEC)
    assert ok.chi2 / ok.dof == pytest.approx(1.0, abs=0.35)
    assert bad.chi2 / bad.dof > 8


def test_ols_matches_gls_within_errors():
    readings, e_true, _ = _simulate(17, list(range(17)))
    g = solve_closure(readings, list(range(17)))
    o = solve_closure(readings, list(range(17)), weighting="ols")
    assert np.all(np.abs(o.instrument_error_rad - e_true) < 5 * o.instrument_se_rad)
    assert np.mean(o.instrument_se_rad) >= np.mean(g.instrument_se_rad) * 0.999


# ----------------------------------------------------------------------------- rank


@pytest.mark.parametrize(
    "n, positions, expected",
    [
        (72, [0, 36], list(range(2, 37, 2))),
        (12, [0, 3, 6, 9], [4]),
        (12, [0], list(range(1, 7))),
        (12, [0, 1], []),
        (72, list(range(15)), []),
    ],
)
def test_undetermined_harmonics(n, positions, expected):
    assert undetermined_harmonics(n, positions) == expected
    deficit = sum(1 if 2 * k == n else 2 for k in expected)
    assert np.linalg.matrix_rank(closure_matrix(n, positions)) == 2 * n - deficit


def test_rank_deficient_is_refused_or_flagged():
    readings, _, _ = _simulate(12, [0, 6])
    with pytest.raises(EncdesignInputError, match=r"rank-deficient.*harmonics \[2, 4, 6\]"):
        solve_closure(readings, [0, 6])
    res = solve_closure(readings, [0, 6], throw=False)
    assert res.status == "rank_deficient"
    assert res.undetermined_harmonics == [2, 4, 6]
    assert res.rank == 24 - 5


# ----------------------------------------------------------------------------- recordings


def _write(tmp_path, n=12, settings=12, seed=0):
    readings, e_true, f_true = _simulate(n, list(range(settings)), seed=seed)
    rec = write_closure_recording(tmp_path / "closure.toml", readings)
    return rec, readings, e_true


def test_recording_round_trip(tmp_path):
    _, readings, e_true = _write(tmp_path)
    rec = load_recording(tmp_path / "closure.toml")
    assert rec.kind == "closure"
    res = closure_from_recording(rec)
    direct = solve_closure(readings, list(range(12)))
    np.testing.assert_allclose(res.instrument_error_rad, direct.instrument_error_rad, atol=1e-15)


def _table(tmp_path, n=4, settings=2):
    rows = ["setting,face,reading"]
    for s in range(settings):
        faces = list(range(n)) + [0]
        for j in faces:
            rows.append(f"{s},{j},{2 * math.pi * ((s + j) % n) / n + 1e-6}")
    return rows


def _write_raw(tmp_path, rows, n=4):
    (tmp_path / "c.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "c.toml").write_text(
        'format = "encdesign-recording/1"\nkind = "closure"\ndata = "c.csv"\n'
        f"[encoder]\nfaces = {n}\n"
    )
    return tmp_path / "c.toml"


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda r: r[:3] + r[4:], r"missing face\(s\) \[2\]"),
        (lambda r: r[:2] + ["0,7,0.5"] + r[3:], r"unknown face index 7"),
        (lambda r: r[:5] + r[6:], r"does not return to face 0"),
        (lambda r: r[:2] + ["0,1,nan"] + r[3:], r"finite"),
        (lambda r: r[:2] + ["0,1,inf"] + r[3:], r"finite"),
        (lambda r: r[:2] + ["0,2,0.5", "0,1,0.3"] + r[4:], r"face 2 where face 1"),
    ],
)
def test_bad_closure_recording_refused(tmp_path, edit, message, capsys):
    path = _write_raw(tmp_path, edit(_table(tmp_path)))
    with pytest.raises(EncdesignInputError, match=message):
        load_recording(path)
    assert main(["calibrate", "closure", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error" in err


def _row(s, j, n=4):
    return f"{s},{j},{2 * math.pi * ((s + j) % n) / n + 1e-6}"


@pytest.mark.parametrize(
    "rows, message, bad_rows",
    [
        # face index outside 0 … N-1: the row itself
        (
            [_row(0, 0), _row(0, 1), "0,7,0.5", _row(0, 3), _row(0, 0)],
            r"unknown face index 7",
            (2,),
        ),
        # out of sequence: the first row that differs
        (
            [_row(0, 0), _row(0, 2), _row(0, 1), _row(0, 3), _row(0, 0)],
            r"face 2 where face 1",
            (1,),
        ),
        # a setting in two blocks: the first row of its second block
        (
            [_row(s, j) for s in (0, 1, 0) for j in (0, 1, 2, 3, 0)],
            r"setting 0 appears in more than one block",
            (10,),
        ),
        # a setting that does not start at face 0: its first row
        ([_row(0, j) for j in (1, 2, 3, 0, 1)], r"starts at face 1", (0,)),
        # no return to face 0: the last face's row
        ([_row(0, j) for j in (0, 1, 2, 3)], r"does not return to face 0", (3,)),
        # rows after the return: the first extra row
        ([_row(0, j) for j in (0, 1, 2, 3, 0, 1)], r"row\(s\) after its return", (5,)),
        # faces missing: the setting's first and last rows
        ([_row(0, j) for j in (0, 1, 3, 0)], r"missing face\(s\) \[2\]", (0, 3)),
    ],
)
@pytest.mark.parametrize("seed", [0, 1])
def test_bad_closure_recording_names_the_file_line(tmp_path, rows, message, bad_rows, seed):
    """The closure check names the line of the file, counted past the blank lines the
    table reader skips (before the first row, between rows), not ``row + 2``."""
    rng = np.random.default_rng(seed)
    lines, line_of = ["setting,face,reading"], {}
    for i, r in enumerate(rows):
        lines += [""] * int(rng.integers(0, 3))
        lines.append(r)
        line_of[i] = len(lines)
    path = _write_raw(tmp_path, lines)
    with pytest.raises(EncdesignInputError, match=message) as exc:
        load_recording(path)
    text = str(exc.value)
    want = "–".join(str(line_of[i]) for i in bad_rows)
    assert f"c.csv, line{'s' if len(bad_rows) > 1 else ''} {want}" in text, text


def test_good_raw_table_loads(tmp_path):
    rec = load_recording(_write_raw(tmp_path, _table(tmp_path)))
    assert rec.n_rows == 10


def test_cli_closure(tmp_path, capsys):
    _write(tmp_path, n=12, settings=12)
    out = tmp_path / "res.json"
    assert (
        main(
            [
                "calibrate",
                "closure",
                str(tmp_path / "closure.toml"),
                "--json",
                str(out),
                "--plots",
                str(tmp_path / "plots"),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "156 measurements, 146 equations, 24 unknowns" in text
    d = json.loads(out.read_text())
    assert d["rank"] == 24 and d["status"] == "ok" and len(d["instrument_error_arcsec"]) == 12
    assert (tmp_path / "plots" / "closure.png").exists()


def test_cli_closure_rank_deficient(tmp_path, capsys):
    readings, _, _ = _simulate(12, [0, 6])
    write_closure_recording(tmp_path / "p.toml", readings)
    assert main(["calibrate", "closure", str(tmp_path / "p.toml")]) == 2
    assert "rank-deficient" in capsys.readouterr().err
    assert main(["calibrate", "closure", str(tmp_path / "p.toml"), "--allow-rank-deficient"]) == 0
    assert "undetermined harmonics [2, 4, 6]" in capsys.readouterr().out


# ----------------------------------------------------------------------------- curve


def test_curve_order_by_heldout_error_and_band():
    readings, e_true, _ = _simulate(72, list(range(15)))
    res = solve_closure(readings, list(range(15)))
    curve = curve_from_closure(res)
    assert curve.order == 2  # the helper instrument has orders 1 and 2 only
    th = res.positions_rad
    assert np.max(np.abs(curve(th) - e_true)) < 4 * np.max(curve.band_rad(th))
    assert curve.heldout_rms_rad[2] < 0.1 * curve.heldout_rms_rad[1]


@pytest.mark.parametrize("true_order", [1, 3, 5])
def test_curve_order_choice_on_generated_data(true_order):
    rng = np.random.default_rng(true_order)
    th = np.sort(rng.uniform(0, 2 * np.pi, 400))
    y = sum(np.cos(k * th + k) * 1e-5 / k for k in range(1, true_order + 1))
    y = y + rng.normal(0, 1e-7, th.size)
    assert fit_curve(th, y, max_order=10).order == true_order


def test_correction_table_round_trip(tmp_path):
    th = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    y = 3e-6 * np.sin(2 * th + 0.4)
    curve = fit_curve(th, y, order=2)
    path = write_correction_table(tmp_path / "t.csv", curve, 3600)
    table = read_correction_table(path)
    reading = th + y
    corrected = apply_correction_table(table, reading)
    assert np.max(np.abs(corrected - th)) < 1e-8


def test_bad_correction_table(tmp_path):
    (tmp_path / "t.csv").write_text("angle,correction\n0,1\n")
    with pytest.raises(EncdesignInputError, match="header"):
        read_correction_table(tmp_path / "t.csv")


def test_cli_curve(tmp_path, capsys):
    _write(tmp_path, n=72, settings=15)
    assert (
        main(
            [
                "calibrate",
                "curve",
                str(tmp_path / "closure.toml"),
                "--table",
                str(tmp_path / "corr.csv"),
                "--json",
                str(tmp_path / "c.json"),
            ]
        )
        == 0
    )
    d = json.loads((tmp_path / "c.json").read_text())
    assert d["order"] == 2
    assert read_correction_table(tmp_path / "corr.csv")[0].size == 3600


# ----------------------------------------------------------------------------- reference


def _three_plus_one(n=2048, coupling_rad=0.0, seed=0):
    import jax.numpy as jnp
    from helpers import cramer_model

    model = cramer_model(noise_rad=1e-7)
    angles = np.deg2rad([0.0, 120.0, 240.0, 22.0])
    theta = 2 * np.pi * np.arange(n) / n
    readings = np.asarray(
        __import__("encdesign").noisy_head_readings(
            model, jnp.asarray(theta), key=jax.random.PRNGKey(seed)
        )
    )
    theta_ref = theta + coupling_rad * np.sin(3 * theta + 0.3)
    return theta, theta_ref, readings, angles


def test_reference_map_recovers_mode3():
    theta, theta_ref, readings, angles = _three_plus_one()
    m = reference_map(theta_ref, readings[:, :3].mean(axis=1), 6)
    i3 = m.orders.index(3)
    assert m.sin_rad[i3] == pytest.approx(5e-6, abs=5 * m.sin_se_rad[i3] + 1e-8)
    cmp = compare_maps(theta_ref, readings, angles, 3, max_order=8)
    assert cmp.max_difference_rad < 0.2e-6
    assert cmp.selfcomp_amplitude_rad == pytest.approx(5e-6, rel=0.05)


def test_coupling_order3_limits_agreement():
    _, theta_ref, readings, angles = _three_plus_one(coupling_rad=3e-6)
    cmp = compare_maps(theta_ref, readings, angles, 3, max_order=8)
    assert cmp.max_difference_rad == pytest.approx(3e-6, rel=0.1)


def test_compare_maps_on_recording(tmp_path):
    theta, theta_ref, readings, angles = _three_plus_one()
    cols = {"t": theta / (2 * np.pi), "theta_ref": theta_ref}
    cols |= {f"h{k}": readings[:, k] for k in range(4)}
    write_recording(
        tmp_path / "m.toml",
        "multihead",
        cols,
        encoder={
            "optical_radius_m": 0.0254,
            "head_angles_deg": [0.0, 120.0, 240.0, 22.0],
            "reference_head": 3,
        },
    )
    cmp = compare_maps_on_recording(load_recording(tmp_path / "m.toml"), max_order=8)
    assert cmp.max_difference_rad < 0.2e-6
    write_recording(
        tmp_path / "n.toml",
        "multihead",
        {k: v for k, v in cols.items() if k != "theta_ref"},
        encoder={"optical_radius_m": 0.0254, "head_angles_deg": [0.0, 120.0, 240.0, 22.0]},
    )
    with pytest.raises(EncdesignInputError, match="theta_ref"):
        compare_maps_on_recording(load_recording(tmp_path / "n.toml"))


# ----------------------------------------------------------------------------- studies


@pytest.mark.parametrize(
    "name, keys",
    [
        ("closure", ["cases", "seed_counts", "all_chi2_consistent", "rank_deficient_example"]),
        (
            "selfcomp-vs-reference",
            ["raw_error_urad", "selfcomp_map_urad", "reference_map_urad", "map_difference_urad"],
        ),
    ],
)
def test_studies_quick(tmp_path, name, keys):
    flags = ["--quick", "--no-plots", "--out", str(tmp_path), "--json", str(tmp_path / "s.json")]
    if name == "closure":
        flags += ["--instruments", "first_two_pairs", "--trials", "2", "--marks", "80"]
    assert main(["study", "run", name, *flags]) == 0
    d = json.loads((tmp_path / "s.json").read_text())
    for k in keys:
        assert k in d
    if name == "closure":
        assert d["all_chi2_consistent"]
        assert d["seed_counts"]["N72_15_settings"]["n_equations"] == 1082
        assert d["rank_deficient_example"]["undetermined_harmonics"][:2] == [2, 4]


def test_seed002_results_quick(tmp_path):
    out = tmp_path / "s.json"
    flags = ["--quick", "--no-plots", "--offsets-bin", "0.5", "--out", str(tmp_path)]
    flags += ["--cases", "700Hz_0.8mm_s", "1400Hz_0.8mm_s"]
    assert main(["study", "run", "seed002-results", *flags, "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    # off the bin, the FFT-resolution f_exc costs compensation; the refined one does not
    assert all(r["error_area_reduction"] > r["error_area_reduction_fft_only"] + 0.2 for r in rows)


# ----------------------------------------------------------------------------- vibration LUT

LUT_PITCH_M = 20e-6
LUT_FS_HZ = 16384.0
LUT_FREQ_HZ = np.arange(200.0, 2001.0, 200.0)  # 10 steps (the vibration-lut --quick sizes)
# injected mounts per direction: (natural frequency Hz, damping ratio)
LUT_MOUNTS = {"x": (1500.0, 0.05), "y": (900.0, 0.08)}
LUT_SIGNAL_ERRORS = (0.04, -0.03, 0.94, 0.07)


def _mount(direction):
    fn, zeta = LUT_MOUNTS[direction]
    return lambda f, a: mount_relative_displacement_m(f, a, fn, zeta)


@pytest.fixture(scope="module")
def lut_bench():
    """One stepped-sine test per direction (10 frequencies x 4 repeats, 1,024 samples each)."""
    import jax.numpy as jnp

    import encdesign as ed

    err = ed.SignalErrors(*LUT_SIGNAL_ERRORS)
    t1 = np.arange(4096) / LUT_FS_HZ
    sa, sb = ed.quadrature_signals(jnp.asarray(2 * np.pi * 4e-3 * t1 / LUT_PITCH_M), err, 0.5)
    params = ed.fit_ellipse(sa, sb, method="direct").params
    steps, luts = {}, {}
    for i, d in enumerate(LUT_MOUNTS):
        steps[d] = simulate_shaker_steps(
            jax.random.PRNGKey(40 + i),
            LUT_FREQ_HZ,
            4,
            _mount(d),
            errors=err,
            signal_period_m=LUT_PITCH_M,
            sample_rate_hz=LUT_FS_HZ,
            n_samples=1024,
            amplitude=0.5,
            noise_std=0.003,
            position_m=0.3 * LUT_PITCH_M,
            direction=d,
        )
        luts[d] = build_stepped_lut(steps[d], params, LUT_PITCH_M)
    return params, steps, luts


def test_mount_closed_form_limits():
    fn, zeta, a = 1000.0, 0.05, 100.0
    wn = 2 * np.pi * fn
    x_lo, ph_lo = mount_relative_displacement_m(1.0, a, fn, zeta)
    x_res, ph_res = mount_relative_displacement_m(fn, a, fn, zeta)
    x_hi, ph_hi = mount_relative_displacement_m(100 * fn, a, fn, zeta)
    assert float(x_lo) == pytest.approx(a / wn**2, rel=1e-5)  # quasi-static: a / wn^2
    assert float(x_res) == pytest.approx(a / (2 * zeta * wn**2), rel=1e-12)  # resonance
    assert float(x_hi) == pytest.approx(a / (2 * np.pi * 100 * fn) ** 2, rel=2e-4)  # mass-like
    assert float(ph_lo) == pytest.approx(np.pi, abs=1e-3)
    assert float(ph_res) == pytest.approx(np.pi / 2, abs=1e-12)
    assert float(ph_hi) == pytest.approx(0.0, abs=2e-3)


@pytest.mark.parametrize("direction", list(LUT_MOUNTS))
def test_stepped_lut_recovers_the_injected_curve(lut_bench, direction):
    _, steps, luts = lut_bench
    lut = luts[direction]
    x, ph = _mount(direction)(LUT_FREQ_HZ, 100.0)
    rel = np.asarray(lut.delta_gm_lut_m) / np.asarray(2 * x) - 1
    assert np.max(np.abs(rel)) < 0.01  # stated tolerance: 1 % at every step
    h = lut.response_m_per_m_s2(LUT_FREQ_HZ)
    assert np.max(np.abs(np.angle(np.asarray(h) * np.exp(-1j * np.asarray(ph))))) < 0.01  # rad
    assert np.allclose(np.abs(np.asarray(h)) * 100.0, np.asarray(x), rtol=0.01)
    # the controller's 5 % scatter is removed by the accelerometer scaling: the plain mean
    # (seed) has an error bar > 10x larger and is still consistent with the truth
    plain = build_stepped_lut(
        steps[direction], lut_bench[0], LUT_PITCH_M, scale_by_accelerometer=False
    )
    assert np.all(np.asarray(plain.delta_gm_se_m) > 10 * np.asarray(lut.delta_gm_se_m))
    z = (np.asarray(plain.delta_gm_lut_m) - np.asarray(2 * x)) / np.asarray(plain.delta_gm_se_m)
    assert np.max(np.abs(z)) < 4.5


def test_accelerometer_scaling_against_the_closed_form(lut_bench):
    lut = lut_bench[2]["x"]
    for a in (30.0, 250.0):
        x, _ = _mount("x")(LUT_FREQ_HZ, a)
        got = np.asarray(lut.delta_gm_m(LUT_FREQ_HZ, a))
        assert np.allclose(got, 2 * np.asarray(x), rtol=0.01)
        se = np.asarray(lut.delta_gm_se_at_m(LUT_FREQ_HZ, a))
        assert np.allclose(se, np.asarray(lut.delta_gm_se_m) * a / 100.0)
    # linear interpolation between steps (seed step 4), clamped outside
    f_mid = 0.5 * (LUT_FREQ_HZ[2] + LUT_FREQ_HZ[3])
    mid = 0.5 * (lut.delta_gm_lut_m[2] + lut.delta_gm_lut_m[3])
    assert float(lut.delta_gm_m(f_mid)) == pytest.approx(float(mid), rel=1e-12)
    assert float(lut.delta_gm_m(10.0)) == pytest.approx(float(lut.delta_gm_lut_m[0]))
    phys = lut.as_vibration_lut(50.0)
    assert float(phys(f_mid)) == pytest.approx(float(mid) / 2, rel=1e-12)


def test_accelerometer_levels_recover_amplitudes():
    rng = np.random.default_rng(5)
    t = np.arange(4096) / LUT_FS_HZ
    amp, ph = np.array([60.0, 25.0, 8.0]), np.array([0.3, 2.0, -1.0])
    acc = amp * np.sin(2 * np.pi * 700.0 * t[:, None] + ph) + rng.normal(0, 2.0, (4096, 3))
    lv = accelerometer_levels(t, acc, 700.0)
    z = (np.asarray(lv.amplitude_m_s2) - amp) / np.asarray(lv.amplitude_se_m_s2)
    assert np.max(np.abs(z)) < 4.5
    assert np.allclose(np.asarray(lv.amplitude_se_m_s2), 2.0 * np.sqrt(2 / 4096), rtol=0.1)
    assert np.allclose(np.asarray(lv.phase_rad), ph, atol=0.01)
    assert lv.as_dict()["x"] == pytest.approx(60.0, rel=0.01)


def test_combined_luts_per_direction(lut_bench):
    import jax.numpy as jnp

    luts = lut_bench[2]
    f = LUT_FREQ_HZ[4]  # 1,000 Hz: between the two resonances, the responses differ in phase
    amp, ph = {"x": 60.0, "y": 25.0}, {"x": 0.3, "y": 2.0}
    levels = AccelerometerLevels(
        jnp.asarray(f),
        jnp.asarray([60.0, 25.0]),
        jnp.asarray([0.3, 2.0]),
        jnp.zeros(2),
        ("x", "y"),
    )
    comb = combine_luts(luts, levels, f)
    zs = []
    for d in ("x", "y"):
        x, p = _mount(d)(f, amp[d])
        zs.append(float(x) * np.exp(1j * (float(p) + ph[d])))
    truth = 2 * abs(sum(zs))  # linear mount: phasors add
    assert float(comb.delta_gm_phasor_m) == pytest.approx(truth, rel=0.01)
    seed_truth = 2 * sum(abs(z) for z in zs)  # the seed's proportional combination
    assert float(comb.delta_gm_seed_m) == pytest.approx(seed_truth, rel=0.01)
    assert float(comb.delta_gm_seed_m) > float(comb.delta_gm_phasor_m)  # an upper bound
    assert np.allclose(np.asarray(comb.weights), [60 / 85, 25 / 85])
    # all in phase (amplitudes only): the seed's combination is the sum of scaled LUTs
    c2 = combine_luts(luts, amp, f)
    assert float(c2.delta_gm_seed_m) == pytest.approx(float(comb.delta_gm_seed_m))


def test_combined_lut_gradient_matches_finite_differences(lut_bench):
    luts = lut_bench[2]
    f = float(LUT_FREQ_HZ[4])

    def g(ax):
        return combine_luts(luts, {"x": ax, "y": 25.0}, f).delta_gm_phasor_m

    ax, h = 60.0, 1e-3
    fd = (float(g(ax + h)) - float(g(ax - h))) / (2 * h)
    assert float(jax.grad(g)(ax)) == pytest.approx(fd, rel=1e-6)


def test_lut_bad_input(lut_bench):
    params, steps, luts = lut_bench
    with pytest.raises(EncdesignInputError, match="without a LUT"):
        combine_luts(luts, {"z": 10.0}, 700.0)
    with pytest.raises(EncdesignInputError, match="repeats"):
        simulate_shaker_steps(
            jax.random.PRNGKey(0),
            LUT_FREQ_HZ,
            1,
            _mount("x"),
            errors=None,
            signal_period_m=LUT_PITCH_M,
            sample_rate_hz=LUT_FS_HZ,
            n_samples=64,
        )
    with pytest.raises(EncdesignInputError, match="increasing"):
        simulate_shaker_steps(
            jax.random.PRNGKey(0),
            LUT_FREQ_HZ[::-1],
            2,
            _mount("x"),
            errors=None,
            signal_period_m=LUT_PITCH_M,
            sample_rate_hz=LUT_FS_HZ,
            n_samples=64,
        )
    bad = steps["x"]
    bad = type(bad)(
        bad.frequency_hz,
        bad.t_s,
        bad.sa,
        bad.sb,
        -bad.acceleration_m_s2,
        bad.acceleration_phase_rad,
        bad.nominal_acceleration_m_s2,
        "x",
    )
    with pytest.raises(EncdesignInputError, match="non-positive"):
        build_stepped_lut(bad, params, LUT_PITCH_M)
    with pytest.raises(EncdesignInputError, match="one label per axis"):
        accelerometer_levels(np.arange(64) / 1e3, np.zeros((64, 2)), 10.0)


def test_vibration_lut_study_quick(tmp_path):
    out = tmp_path / "s.json"
    flags = ["--quick", "--no-plots", "--cases-hz", "1000", "--out", str(tmp_path)]
    assert main(["study", "run", "vibration-lut", *flags, "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert all(r["max_relative_error_scaled"] < 0.02 for r in d["luts"].values())
    v = d["cases"][0]["variants"]
    # the field is not at the LUT's 100 m/s^2 and not along x only: the phasor combination
    # gets delta_gm right, the seed's in-phase sum over-estimates it, the x LUT alone misses
    assert abs(v["phasor_combined"]["delta_gm_relative_error"]) < 0.05
    assert v["seed_combined"]["delta_gm_relative_error"] > 0
    assert v["phasor_combined"]["error_area_reduction"] > v["x_lut_scaled"]["error_area_reduction"]


# ----------------------------------------------------------------------------- drive study


@pytest.fixture(scope="module")
def drive():
    import encdesign as ed
    from encdesign.cli._main import _load_study

    mod = _load_study("sds-drive")
    return mod, ed.reference_design(2, 2, marks_per_rev=240)


def test_drive_simulation_reproduces_the_project_motor_model(drive):
    import jax.numpy as jnp

    import encdesign as ed

    mod, design = drive
    motion = mod.simulate_motion(
        design.motor, jax.random.PRNGKey(0), n_revs=2, steps_per_rev=1024, ripple_in_time=True
    )
    phis = (0.3, 3.4)
    ours = np.array([mod.sds_errors(design, motion, p, [1]).mean() for p in phis])
    ref = np.asarray(ed.sds_phi_error(design, jnp.asarray(phis)))
    assert np.max(np.abs(ref)) > 0.05 * ARCSEC  # the ripple x mark-error term is there
    assert np.max(np.abs(ours - ref)) < 1e-3 * np.max(np.abs(ref))


def test_closed_loop_on_hall_feedback_varies_more_than_open_loop(drive):
    mod, design = drive
    key = jax.random.PRNGKey(1)
    common = dict(n_revs=8, warm=6, steps_per_rev=512)
    ol = mod.run_case(design, key, dict(wander_std=2e-4), **common)
    cl = mod.run_case(
        design, key, dict(wander_std=2e-4, closed_loop=True, bandwidth_hz=20.0), **common
    )
    # seed: closed loop speed control, "much larger variation … on successive revolutions"
    ratio = cl["rev_to_rev_std_arcsec_all_pairs"] / ol["rev_to_rev_std_arcsec_all_pairs"]
    assert ratio > 2
    # the loop follows its sensitivity on the repeatable ripple (ideal feedback)
    ideal = dict(closed_loop=True, bandwidth_hz=20.0, placement=False, timer=False, pwm_step=0.0)
    cl0 = mod.run_case(design, key, ideal, **common)
    w0 = float(design.motor.speed_rad_s)
    wc = float(design.motor.corner_order) * w0
    for n in (1, 2, 6):
        got = cl0["speed_ripple_by_order"][n - 1] / ol["speed_ripple_by_order"][n - 1]
        s_pred = abs(1 / (1 + mod.loop_transfer(n * w0 / (2 * np.pi), 20.0, wc, 36, w0)))
        assert got == pytest.approx(s_pred, rel=0.15)
