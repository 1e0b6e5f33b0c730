"""A line at one speed that the sampling folds from a catalog order (issue 44): generated
multihead records of one steady run with an interpolation error mostly at ``2 L`` (an
amplitude mismatch, largest on one head), with and without ``theta_ref``, several head counts,
line counts and spans; and, as the control, a vibration off those orders."""

from __future__ import annotations

import numpy as np
import pytest

import encdesign
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.kinds.multihead._aliases import folded_hz
from tests.helpers import sweep, validate_diagnosis

NOISE = 0.5e-6
FS = 200.0


def _one_run(seed: int, *, interp: bool, n: int = 400) -> tuple[encdesign.Recording, dict]:
    """One steady run of ``n`` rows at 200 Hz, 0.5 urad noise, disk errors of orders 1-5;
    the heads, lines, span and ``theta_ref`` drawn from ``seed``; an interpolation error
    (``2 L`` at 0.3-0.6x the noise per head, 2.5x on one, ``L`` at 0.1-0.3x) or a vibration
    (2x the noise, its own phase per head) at a frequency away from the folded ``L``, ``2 L``."""
    rng = np.random.default_rng(seed)
    H = int(rng.integers(3, 5))
    L = int(rng.choice([1024, 2048, 2500, 3600, 5000, 10000]))
    turns = float(rng.uniform(0.5, 3.0))
    ref = bool(rng.integers(2))
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.5, 5.8, H - 1))])
    t = np.arange(n) / FS
    w = 2 * np.pi * turns / (n / FS)
    th = w * t + rng.uniform(0, 6.28)
    err = np.zeros((n, H))
    for m in range(1, 6):
        err += 8 * NOISE / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6.28))
    truth = {"H": H, "L": L, "turns": turns, "ref": ref}
    if interp:
        psi = L * (th[:, None] + err)
        a2 = rng.uniform(0.3, 0.6, H) * rng.choice([-1, 1], H)
        a2[rng.integers(H)] = 2.5 * rng.choice([-1, 1])
        a1 = rng.uniform(0.1, 0.3, H) * rng.choice([-1, 1], H)
        err += NOISE * (a1 * np.cos(psi) + a2 * np.sin(2 * psi))
    else:
        folded = [folded_hz(m * w / (2 * np.pi), 1 / FS) for m in (L, 2 * L)]
        f = float(rng.uniform(10.0, 90.0))
        while min(abs(f - g) for g in folded) < 3.0:
            f = float(rng.uniform(10.0, 90.0))
        truth["frequency_hz"] = f
        err += 2 * NOISE * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 6.28, H))
    read = th[:, None] + err + rng.normal(0, NOISE, err.shape)
    read += rng.integers(-3, 4, H) * 2 * np.pi + rng.uniform(-3, 3, H)
    cols = {"t": t, "run": np.zeros(n, int)}
    if ref:
        cols["theta_ref"] = th.copy()
    for k in range(H):
        cols[f"h{k}"] = read[:, k]
    enc = {
        "optical_radius_m": 0.02,
        "head_angles_deg": np.degrees(alpha).tolist(),
        "grating_lines": L,
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return encdesign.Recording("multihead", meta, cols), truth


def test_folded_frequency():
    assert folded_hz(240.4, 1 / 196.25) == pytest.approx(44.15)
    assert folded_hz(480.8, 1 / 196.25) == pytest.approx(88.3)
    assert folded_hz(30.0, 1 / 200.0) == pytest.approx(30.0)


@pytest.mark.parametrize("seed", [7485, 7486])
def test_an_interpolation_error_folded_onto_one_line_is_not_a_vibration(seed):
    """At one speed the interpolation error's ``2 L`` is one line at its folded frequency,
    which a vibration fits with fewer parameters; a line fixed in time there is that order
    until two speeds separate them, so the interpolation error is named (before: vibration,
    with interpolation_error only as its confounded partner)."""
    rec, truth = _one_run(seed, interp=True)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    named = [e["name"] for e in d.effects]
    assert named == ["interpolation_error"], (truth, d.doc["report"])
    vib = [r for r in d.doc["rejected"] if r["name"] == "vibration"]
    assert vib and "folded by the sampling" in vib[0]["reason"], (truth, d.doc["report"])


# ``make test`` runs 7492; 7495, another draw of the same control, is the ``sweep`` tier
# (session 33, CI time)
@pytest.mark.parametrize("seed", sweep([7492, 7495], (7492,)))
def test_a_vibration_off_the_folded_orders_is_still_named(seed):
    """The control: a line at one speed away from the folded ``L`` and ``2 L`` is named
    vibration at its frequency."""
    rec, truth = _one_run(seed, interp=False)
    d = diagnose(rec)
    named = {e["name"]: e for e in d.doc["effects"]}
    assert list(named) == ["vibration"], (truth, d.doc["report"])
    f = named["vibration"]["params"]["frequency_hz"]["value"]
    assert f == pytest.approx(truth["frequency_hz"], abs=0.1)
