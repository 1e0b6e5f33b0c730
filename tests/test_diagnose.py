"""Discrepancy-finder engine: terms and gradients, nuisances (per-run zeros, non-steady
segments, glitches, count jumps, gaps), honest verdicts, effects recovered, one sensor
against a reference, user candidates, refusals, the JSON contract, CLI and studies."""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import encdesign
from encdesign.cli import main as cli_main
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.engine._fit import valjac_fn
from encdesign.diagnose.kinds.multihead._multihead import VIBRATION, _base_candidate
from encdesign.physics import _effects as fx
from tests.helpers import validate_diagnosis

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
NOISE = 0.5e-6


def _bench(
    seed: int,
    *,
    H: int = 3,
    R: int = 2,
    n: int = 500,
    ref: bool = True,
    per_run_zeros: bool = True,
    start_move: int = 0,
    bump: bool = False,
    glitch: bool = False,
    jump: float = 0.0,
    gap: bool = False,
    vibration_hz: float = 0.0,
    drift_rad_per_k: float = 0.0,
    one_head_order: tuple[int, int] | None = None,
    beam_tilt_order: int = 0,
    wobble: bool = False,
    ecc_shift: float = 0.0,
    interp: float = 0.0,
    alpha_deg: tuple[float, ...] | None = None,
    pause_s: float | None = None,
    path: Path | None = None,
):
    """A small multihead bench: disk errors of orders 1-5, ``R`` runs of ``n`` rows at
    200 Hz and 1-1.6 rev/s, 0.5 urad noise, and the nuisances / effects asked for."""
    rng = np.random.default_rng(seed)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.5, 5.8, H - 1))])
    if alpha_deg is not None:  # a given layout (the draw above keeps the seed's stream)
        alpha = np.radians(np.asarray(alpha_deg, float))
    ts, ths, runs = [], [], []
    for r in range(R):
        t = np.arange(n) / 200.0
        if pause_s is not None:  # one clock for the record: each run after a pause
            t = t + r * (n / 200.0 + pause_s)
        if gap and r == 0:
            t[n // 2 :] += 0.7
        w = 2 * np.pi * (1.0 + 0.6 * r)
        th = w * t + rng.uniform(0, 6.28)
        if start_move and r == 0:  # start-up from rest over start_move rows
            s = np.minimum(np.arange(n) / start_move, 1.0)
            th = th[0] + np.cumsum(w * s) / 200.0
        ts.append(t)
        ths.append(th)
        runs.append(np.full(n, r))
    t, th, run = np.concatenate(ts), np.concatenate(ths), np.concatenate(runs)
    truth: dict = {"alpha": alpha}
    temp = 21.0 + 0.5 * np.sin(np.arange(t.size) / t.size * 5.0)
    err = np.zeros((t.size, H))
    for m in range(1, 6):
        a, ph = 8 * NOISE / m, rng.uniform(0, 6.28)
        err += a * np.sin(m * (th[:, None] - alpha[None, :]) + ph)
    if vibration_hz:
        ph = rng.uniform(0, 6.28, (R, H))[run]
        err += 2 * NOISE * np.sin(2 * np.pi * vibration_hz * t[:, None] + ph)
    if drift_rad_per_k:
        kap = drift_rad_per_k * np.array([1.0, -0.5, 0.3][:H])
        err += (temp - temp.mean())[:, None] * kap[None, :]
    if one_head_order:  # an out-of-catalog order on one head only, 6x the noise
        k, m = one_head_order
        err[:, k] += 6 * NOISE * np.sin(m * th + rng.uniform(0, 6.28))
    if beam_tilt_order:  # axial runout through tilted beams: one phase, a size per head
        beta = np.array([1.0, -0.6, 0.35, -0.8][:H])
        if not ref:
            beta = beta - beta.mean()
        m = beam_tilt_order
        err += 6 * NOISE * np.sin(m * th + rng.uniform(0, 6.28))[:, None] * beta[None, :]
    if wobble:  # bearing cage wobble at 0.4 of the shaft, seen at each head's azimuth
        ph = rng.uniform(0, 6.28, R)[run]
        err += 6 * NOISE * np.sin(0.4 * th[:, None] + ph[:, None] - alpha[None, :])
    if ecc_shift:  # the disk moves on its hub at 60 % of run 1: order 1 changes at every head
        i0 = n + int(0.6 * n)
        ph = rng.uniform(0, 6.28)
        err[i0:] += ecc_shift * NOISE * np.sin(th[i0:, None] - alpha[None, :] + ph)
        truth["shift_row"] = i0
    if interp:  # offset and amplitude errors of the quadrature signals, L = 2048
        psi = 2048 * (th[:, None] + err)
        o = interp * NOISE * np.array([[1.0, -0.8, 0.9, -0.7][:H], [0.6, 0.9, -1.0, 0.8][:H]])
        err = err + o[0] * np.cos(psi) + o[1] * np.sin(2 * psi)
    if bump:  # a transient error during steady motion: a 0.3 s decaying bump on head 1
        i0 = n // 3
        tt = t[i0 : i0 + 60] - t[i0]
        err[i0 : i0 + 60, 1] += 8 * NOISE * np.exp(-tt / 0.1)
    read = th[:, None] + err + rng.normal(0, NOISE, err.shape)
    if start_move:  # the move shakes the heads (excluded, so it must not matter)
        read[:start_move] += 30 * NOISE * np.sin(np.arange(start_move) * 0.9)[:, None]
    ref_col = th.copy()
    if per_run_zeros:
        for r in range(R):
            m = run == r
            read[m] += rng.integers(-3, 4, H) * 2 * np.pi + rng.uniform(-3, 3, H)
            ref_col[m] += rng.integers(-2, 3) * 2 * np.pi + rng.uniform(-3, 3)
    if glitch:
        i = n + n // 2 + 7
        read[i, 2 % H] += 200 * NOISE
        truth["glitch"] = (1, float(t[i]), f"h{2 % H}")
    if jump:
        i = n // 2 + 31
        read[i:n, 0] += jump
        truth["jump"] = (0, float(t[i]), "h0", jump)
    cols = {"t": t, "run": run, "temp_c": temp}
    if ref:
        cols["theta_ref"] = ref_col
    for k in range(H):
        cols[f"h{k}"] = read[:, k]
    enc = {"optical_radius_m": 0.02, "head_angles_deg": np.degrees(alpha).tolist()}
    if interp:
        enc["grating_lines"] = 2048
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    if path is not None:
        return encdesign.write_recording(path, "multihead", cols, encoder=enc), truth
    return encdesign.Recording("multihead", meta, cols), truth


def test_interpolation_first_order_matches_arctangent():
    psi = jnp.linspace(0, 2 * jnp.pi, 257)[:, None]
    L = 1000
    o = jnp.array([1e-3]), jnp.array([-2e-3]), jnp.array([1.5e-3]), jnp.array([-1e-3])
    exact = fx.interpolation_error_exact_rad(psi / L, L, *o)
    coef = jnp.stack([o[0], -o[1], -o[3] / 2, -o[2] / 2])
    lin = fx.interpolation_harmonics_rad(psi, L, coef) + o[3] / 2 / L
    assert float(jnp.max(jnp.abs(exact - lin))) < 1e-2 * float(jnp.max(jnp.abs(exact)))


def test_wobble_cancels_in_opposed_heads_and_eccentricity_formula():
    th = jnp.linspace(0, 20, 400)
    al = jnp.array([0.3, 0.3 + jnp.pi])
    w = fx.bearing_wobble_rad(th, al, 0.02, 0.4, jnp.full(400, 1e-7), jnp.full(400, 2e-7))
    assert float(jnp.max(jnp.abs(w.sum(1)))) < 1e-18
    e = fx.eccentricity_rad(th, al, 0.02, 1e-6, 0.0)
    assert float(jnp.max(jnp.abs(e[:, 0] - 5e-5 * jnp.sin(th - 0.3)))) < 1e-18


@pytest.mark.parametrize("which", ["base", "vibration"])
def test_term_jacobian_matches_central_differences(which):
    """The engine's Jacobian (jax.jacfwd of each term) against central differences."""
    rng = np.random.default_rng(0)
    n, C, R = 64, 3, 2
    oh = np.zeros((n, R))
    oh[np.arange(n), np.arange(n) % R] = 1.0
    x = {
        "theta_raw": jnp.asarray(rng.uniform(0, 20, n)),
        "theta": jnp.asarray(rng.uniform(0, 20, n)),
        "t": jnp.asarray(np.sort(rng.uniform(0, 3, n))),
        "run_onehot": jnp.asarray(oh),
        "alpha": jnp.asarray([0.0, 2.0, 4.0]),
        "reading": jnp.zeros((n, C)),
    }
    if which == "base":
        cand = _base_candidate(C, R, 4)
        p = {
            "offset_rad": rng.normal(0, 1e-6, (R, C)),
            "fourier_cos_rad": rng.normal(0, 1e-5, 4),
            "fourier_sin_rad": rng.normal(0, 1e-5, 4),
            "placement_rad": rng.normal(0, 1e-3, C - 1),
            "run_angle_offset_rad": rng.normal(0, 0.3, R - 1),
        }
    else:
        cand = VIBRATION
        p = {
            "frequency_hz": np.asarray(17.3),
            "cos_rad": rng.normal(0, 1e-6, R * C),
            "sin_rad": rng.normal(0, 1e-6, R * C),
        }
    p = {k: jnp.asarray(v, dtype=float) for k, v in p.items()}
    _, J = valjac_fn(cand)(p, x)
    for name, v in p.items():
        flat = np.asarray(v).ravel()
        h = 1e-6 * max(float(np.max(np.abs(flat))), 1e-6)
        for i in range(flat.size):
            up, dn = flat.copy(), flat.copy()
            up[i] += h
            dn[i] -= h
            fu = cand.fn({**p, name: jnp.asarray(up.reshape(v.shape))}, x)
            fd = cand.fn({**p, name: jnp.asarray(dn.reshape(v.shape))}, x)
            num = (np.asarray(fu) - np.asarray(fd)) / (2 * h)
            ana = np.asarray(J[name]).reshape(n, C, -1)[:, :, i]
            scale = max(float(np.max(np.abs(ana))), 1e-30)
            assert float(np.max(np.abs(num - ana))) < 1e-5 * scale + 1e-12, (name, i)


@pytest.mark.parametrize("ref", [True, False])
def test_clean_record_with_per_run_zeros_and_a_gap_is_consistent(ref):
    rec, _ = _bench(1 if ref else 2, ref=ref, gap=ref)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert d.verdict == "consistent", d.doc["report"]
    g = d.doc["goodness_of_fit"]
    assert g["passes"] and 0.0 <= g["p_value"] <= 1.0 and "statistic_z" in g
    assert d.doc["heldout"]["k"] >= 4
    assert d.doc["glitches"] == [] and d.doc["count_jumps"] == []
    if ref:
        assert len(d.doc["gaps"]) == 1 and d.doc["gaps"][0]["run"] == 0


def test_start_move_is_excluded_and_reported():
    rec, _ = _bench(3, start_move=80)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    ex = d.doc["excluded_segments"]
    assert len(ex) == 1 and ex[0]["run"] == 0 and ex[0]["t_start_s"] == 0.0
    assert "start-up" in ex[0]["reason"] or "speed" in ex[0]["reason"]
    # the move ends at row 80 (0.4 s): the exclusion ends there, within the settling window
    assert 0.4 <= ex[0]["t_end_s"] <= 0.4 * 1.1 + 0.05
    assert d.verdict == "consistent", d.doc["report"]


def test_transient_error_is_never_consistent():
    rec, _ = _bench(4, bump=True)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert d.verdict != "consistent"
    assert not d.doc["goodness_of_fit"]["passes"] or d.doc["unexplained"]


def test_glitch_and_count_jump_are_located_and_the_rest_consistent():
    jump = 2 * np.pi / 4000  # one count of a 1000-line encoder read in quadrature
    rec, truth = _bench(5, glitch=True, jump=jump)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    (g,) = d.doc["glitches"]
    assert (g["run"], g["channel"]) == truth["glitch"][::2] and g["t_s"] == truth["glitch"][1]
    (j,) = d.doc["count_jumps"]
    assert (j["run"], j["channel"]) == (0, "h0") and j["t_s"] == truth["jump"][1]
    assert j["size"] == pytest.approx(jump, rel=0.1)
    assert d.verdict == "consistent", d.doc["report"]


def test_vibration_recovered_within_10_percent():
    rec, _ = _bench(6, vibration_hz=37.0)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    (e,) = d.effects
    assert e["name"] == "vibration"
    assert e["params"]["frequency_hz"]["value"] == pytest.approx(37.0, rel=0.1)
    amp = np.hypot(e["params"]["cos_rad"]["value"], e["params"]["sin_rad"]["value"])
    assert np.median(amp) == pytest.approx(2 * NOISE, rel=0.1)
    assert e["heldout_rms_after"] < d.doc["heldout_rms_before"]
    assert e["params"]["frequency_hz"]["se"] > 0


def test_thermal_drift_recovered_within_10_percent():
    kap = 3.4e-6  # seed 001: about 0.7 arcsec/K
    rec, _ = _bench(7, drift_rad_per_k=kap)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert [e["name"] for e in d.effects] == ["thermal_drift"]
    got = np.asarray(d.effects[0]["params"]["rate"]["value"])
    np.testing.assert_allclose(got, kap * np.array([1.0, -0.5, 0.3]), rtol=0.1, atol=0.1 * kap)


@pytest.mark.parametrize("ref", [True, False])
def test_out_of_catalog_order_on_one_head_is_located_on_that_head_only(ref):
    """The issue's case: an order no candidate has (7), on head 2 of 4, with and without
    theta_ref: unexplained, at order 7, on head 2 only (without a reference the other heads
    show it through the heads' mean, and the base model's disk error takes a part)."""
    rec, _ = _bench(11 if ref else 12, H=4, ref=ref, one_head_order=(2, 7))
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert d.verdict == "unexplained" and not d.effects, d.doc["report"]
    at7 = [u for u in d.doc["unexplained"] if any(abs(o - 7) < 0.15 for o in u["where"]["orders"])]
    assert at7 and all(u["where"]["heads"] == [2] for u in at7), d.doc["unexplained"]


@pytest.mark.parametrize(("ref", "H", "order"), [(True, 4, 1), (False, 4, 1), (True, 2, 3)])
def test_axial_beam_tilt_is_named(ref, H, order):
    """The issue's case: axial beam tilt (a head-specific size, one phase), with and without
    theta_ref, is named beam_tilt_axial (not unexplained). Two heads with theta_ref: the
    product form beta_k z_m held the base's own pattern in its tangent space (refused as
    ill-conditioned); the term is now its head-specific part, linear, the base span out."""
    rec, _ = _bench(13 if ref else 14, H=H, ref=ref, beam_tilt_order=order)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert [e["name"] for e in d.effects] == ["beam_tilt_axial"], d.doc["report"]
    assert d.effects[0]["heldout_rms_after"] < d.doc["heldout_rms_before"]
    assert d.effects[0]["derived"]["orders_fitted"]["value"] == [order]


@pytest.mark.parametrize(("size", "tilt"), [(1.0, 0), (2.0, 2)])
def test_eccentricity_shift_over_many_turns_is_located_and_named(size, tilt):
    """The disk moves on its hub (order 1 changes at one instant, at every head phase-shifted
    by its azimuth) over many turns, alone at 1x the noise or with an axial beam tilt at
    order 2: block means average it out, so the time view cannot place it (before: named
    nothing, or only the tilt); the order_step view scans the change time of the
    eccentricity columns and eccentricity_shift is named at that time."""
    rec, truth = _bench(21, H=3, R=2, n=1500, ecc_shift=size, beam_tilt_order=tilt)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    want = ["beam_tilt_axial", "eccentricity_shift"] if tilt else ["eccentricity_shift"]
    assert sorted(e["name"] for e in d.effects) == want, d.doc["report"]
    # reported on the recording's own clock (here one per run), with its run (issue 44 C)
    t_true = float(rec.columns["t"][truth["shift_row"]])
    es = next(e for e in d.effects if e["name"] == "eccentricity_shift")
    assert es["params"]["shift_time_s"]["run"] == 1
    assert abs(float(np.ravel(es["params"]["shift_time_s"]["value"])[0]) - t_true) < 0.05
    if not tilt:  # alone, the view locates it in the base residual, in run 1, at its row
        f = [f for f in d.doc["findings_before"] if f["view"] == "order_step"]
        assert f and f[0]["where"]["runs"] == [1], d.doc["findings_before"]
        assert abs(f[0]["where"]["times_s"][1] - t_true) < 0.05
    assert d.doc["goodness_of_fit"]["passes"], d.doc["report"]


def test_interpolation_error_with_per_run_zeros_is_one_effect():
    """Per-run head zeros by any amount move the signal phase psi = L * reading by a
    constant per run and head, which rotates the interpolation harmonics: one coefficient
    set per run and head, so no vibration is fitted to the rest of an aliased line."""
    rec, _ = _bench(22, H=3, R=2, n=800, interp=2.0)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert [e["name"] for e in d.effects] == ["interpolation_error"], d.doc["report"]
    assert d.doc["goodness_of_fit"]["passes"], d.doc["report"]


def test_bearing_wobble_without_a_reference_is_named():
    """The issue's case: a bearing wobble (0.4 of the shaft) without theta_ref is named
    bearing_wobble with its frequency ratio within 10 %."""
    rec, _ = _bench(15, H=3, R=2, n=1500, ref=False, wobble=True)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert [e["name"] for e in d.effects] == ["bearing_wobble"], d.doc["report"]
    nu = d.effects[0]["params"]["frequency_ratio"]["value"]
    assert float(np.asarray(nu).ravel()[0]) == pytest.approx(0.4, rel=0.1)


def test_one_sensor_against_a_reference_both_directions():
    """One head, theta_ref, no optical radius, two directions with a reversal: the reversal
    is excluded and the sensor's own error function (orders 1-4, mrad) is the base."""
    rng = np.random.default_rng(8)
    n = 1200
    t = np.arange(n) / 100.0
    up = np.linspace(0, 2 * np.pi, n // 2)
    th = np.concatenate([up, up[::-1]]) + 0.3
    err = sum(1e-3 / m * np.sin(m * th + m) for m in range(1, 5))
    read = th + err + rng.normal(0, 2e-5, n)
    cols = {"t": t, "theta_ref": th, "h0": read}
    meta = {
        "format": "encdesign-recording/1",
        "kind": "multihead",
        "encoder": {"head_angles_deg": [0.0], "sensor": "magnetic"},
    }
    d = diagnose(encdesign.Recording("multihead", meta, cols))
    validate_diagnosis(d.doc)
    assert any("revers" in e["reason"] for e in d.doc["excluded_segments"])
    assert d.verdict == "consistent", d.doc["report"]
    amp = np.hypot(
        d.doc["base"]["terms"]["base"]["fourier_cos_rad"]["value"][:4],
        d.doc["base"]["terms"]["base"]["fourier_sin_rad"]["value"][:4],
    )
    np.testing.assert_allclose(amp, 1e-3 / np.arange(1, 5), rtol=0.1)


def test_user_candidate_from_examples_is_named_by_the_cli(tmp_path, capsys):
    """examples/custom_candidate.py registers a belt ripple (not in the catalog)."""
    rec, _ = _bench(9, path=tmp_path / "b.toml", R=1, n=900)
    cols = dict(rec.columns)
    th = cols["theta_ref"]
    cols["h1"] = cols["h1"] + 3 * NOISE * np.sin(2.7 * th + 0.4)
    rec = encdesign.write_recording(tmp_path / "belt.toml", "multihead", cols, encoder=rec.encoder)
    out = tmp_path / "d.json"
    rc = cli_main(
        [
            "diagnose",
            str(rec.path),
            "--json",
            str(out),
            "--candidates",
            str(EXAMPLES / "custom_candidate.py"),
            "--plots",
            str(tmp_path / "p"),
            "--quiet",
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    validate_diagnosis(doc)
    assert [e["name"] for e in doc["effects"]] == ["belt_ripple"]
    assert doc["effects"][0]["channels"] == ["h1"]
    assert len(list((tmp_path / "p").glob("*.png"))) == 3
    assert "verdict: missing_physics" in capsys.readouterr().out


def test_refusals_exit_2_with_one_message(tmp_path, capsys):
    rec, _ = _bench(10, path=tmp_path / "r.toml", R=1, n=300)
    o = tmp_path / "o.json"
    assert cli_main(["diagnose", str(rec.path), "--json", str(o), "--max-order", "500"]) == 2
    err = capsys.readouterr().err
    assert "resolves orders up to" in err and err.count("\n") == 1
    assert not o.exists()
    (tmp_path / "one.csv").write_text(
        "t,h0\n" + "".join(f"{i * 0.01},{i * 0.1}\n" for i in range(200))
    )
    (tmp_path / "one.toml").write_text(
        'format = "encdesign-recording/1"\nkind = "multihead"\ndata = "one.csv"\n'
        "[encoder]\nhead_angles_deg = [0.0]\n"
    )
    assert cli_main(["diagnose", str(tmp_path / "one.toml"), "--json", str(o)]) == 2
    assert "theta_ref" in capsys.readouterr().err
    bad = tmp_path / "bad.py"
    bad.write_text("X = 1\n")
    assert cli_main(["diagnose", str(rec.path), "--json", str(o), "--candidates", str(bad)]) == 2
    assert "CANDIDATES" in capsys.readouterr().err
    (tmp_path / "bad.toml").write_text('format = "encdesign-recording/1"\nkind = "multihead"\n')
    assert cli_main(["diagnose", str(tmp_path / "bad.toml"), "--json", str(o)]) == 2
    assert not o.exists()


def test_conceal_benchmark_study_quick(tmp_path):
    rc = cli_main(
        [
            "study",
            "run",
            "conceal-benchmark",
            "--quick",
            "--out",
            str(tmp_path / "b"),
            "--json",
            str(tmp_path / "s.json"),
            "--no-plots",
        ]
    )
    assert rc == 0
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["n_recordings"] >= 4
    for kind, block in s["kinds"].items():
        assert "confusion" in block, kind
    assert s["overall"]["clean_consistent_pct"] is not None


def test_diagnose_example_study_quick(tmp_path):
    out = tmp_path / "ex"
    rc = cli_main(["study", "run", "diagnose-example", "--quick", "--out", str(out)])
    assert rc == 0
    s = json.loads((out / "diagnose-example.json").read_text())
    validate_diagnosis(s["diagnosis"])
    assert s["diagnosis"]["verdict"] == "missing_physics"
    assert s["diagnosis"]["effects"][0]["name"] == "vibration"
    assert (out / "residual_spectra.png").exists() and (out / "report.txt").exists()


def test_quadrature_json_follows_the_same_contract(tmp_path):
    """The quadrature kind is on the engine: its JSON has the goodness of fit and folds."""
    rng = np.random.default_rng(1)
    phi = rng.uniform(0, 2 * np.pi, 800)
    sa = 0.02 + np.cos(phi) + rng.normal(0, 1e-3, 800)
    sb = -0.01 + 0.97 * np.cos(phi + 0.01 - np.pi / 2) + rng.normal(0, 1e-3, 800)
    rec = encdesign.write_recording(tmp_path / "q.toml", "quadrature", {"sa": sa, "sb": sb})
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert d.verdict == "consistent"
    assert d.doc["goodness_of_fit"]["passes"] and d.doc["heldout"]["k"] >= 4
    assert not any("not yet routed" in n for n in d.doc["notes"])


@pytest.mark.parametrize(
    ("seed", "H", "vib", "start"),
    [(31, 3, False, 0), (32, 4, True, 0), (33, 5, False, 70), (34, 8, True, 0)],
)
def test_equally_spaced_heads_without_a_reference_fit_normally(seed, H, vib, start):
    """Issue 44 A: equally spaced heads without theta_ref see the disk orders that are
    multiples of H the same at every head (they cancel in head differences, so the common
    rotation is unobservable). The base held them, and the shaft refinement (the fitted
    error's head mean: exactly those orders) never diverges: the base residual is the
    noise, a clean record is consistent and a vibration is named."""
    step = 360.0 / H
    rec, _ = _bench(
        seed,
        H=H,
        ref=False,
        n=600,
        start_move=start,
        vibration_hz=37.0 if vib else 0.0,
        alpha_deg=tuple(step * k for k in range(H)),
    )
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert "fit_failures" not in d.doc["base"] or not d.doc["base"]["fit_failures"]
    assert d.doc["status"] == "ok", d.doc["report"]
    if vib:
        assert [e["name"] for e in d.effects] == ["vibration"], d.doc["report"]
        assert d.effects[0]["rms_after"] < 1.2 * NOISE, d.doc["report"]
    else:
        assert d.verdict == "consistent", d.doc["report"]
        assert d.doc["rms_before"] < 1.2 * NOISE, d.doc["report"]
    held = [u for u in d.doc["base"]["unidentifiable"] if "fourier" in u]
    assert any(f"[{H - 1}]" in u for u in held), d.doc["base"]["unidentifiable"]


def test_a_diverging_shaft_refinement_is_reported_and_the_fit_recovers(monkeypatch):
    """Issue 44 A: with the symmetric orders left free (the base before the fix), the
    fit gives them any size and the shaft refinement's fixed point would diverge: it is
    detected (slope of the head mean), reported under base.fit_failures with its cause,
    undone, and never reaches the verdict (a clean record stays consistent)."""
    import encdesign.diagnose.kinds.multihead._multihead as mh

    monkeypatch.setattr(mh, "_symmetric_orders", lambda prep, M, limit=None: [])
    rec, _ = _bench(35, H=4, ref=False, n=600, alpha_deg=(0.0, 90.0, 180.0, 270.0))
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    fails = d.doc["base"].get("fit_failures", [])
    assert [f["stage"] for f in fails] == ["refine"], d.doc["report"]
    assert "slope" in fails[0]["cause"] and "fit failure" in d.doc["report"]
    assert "refined" not in d.doc["base"]
    assert d.verdict == "consistent", d.doc["report"]


@pytest.mark.parametrize(("seed", "H", "pause"), [(41, 3, 7.0), (42, 4, 2.5), (43, 3, None)])
def test_located_change_time_is_in_the_recordings_own_clock(seed, H, pause):
    """Issue 44 C: an eccentricity shift 60 % into the second run is reported at its time
    on the recording's own ``t`` (one clock with pauses between runs, or a clock per run),
    with its run and an uncertainty that holds the truth; the located change point too."""
    rec, truth = _bench(seed, H=H, R=2, n=1500, ecc_shift=2.5, pause_s=pause)
    t_true = float(rec.columns["t"][truth["shift_row"]])
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    es = next((e for e in d.effects if e["name"] == "eccentricity_shift"), None)
    assert es is not None, d.doc["report"]
    p = es["params"]["shift_time_s"]
    got, se = float(np.ravel(p["value"])[0]), float(np.ravel(p["se"])[0])
    assert p["run"] == 1 and 0 < se < 0.5, p
    assert abs(got - t_true) <= 3 * se + 1 / 200, (got, se, t_true)
    f = [f for f in d.doc["findings_before"] if f["view"] == "order_step"]
    assert f and f[0]["where"]["runs"] == [1], d.doc["findings_before"]
    lo, hi = f[0]["where"]["times_s"]
    assert lo - 1 / 200 <= t_true <= hi + 1 / 200, (lo, hi, t_true)
