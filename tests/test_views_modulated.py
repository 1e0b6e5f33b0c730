"""The ``modulated_orders`` view (issue 41): orders whose amplitude grows or switches over
the record, which the static ``orders`` scan keeps only part of; and the runs' angle zeros
held where a structure not the same in every run pulled them (multihead base)."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from encdesign.diagnose import FinderSettings
from encdesign.diagnose.engine._views import chi2_threshold
from encdesign.diagnose.engine._views_modulated import scan_modulated
from encdesign.diagnose.engine._views_sums import ViewSums
from encdesign.diagnose.kinds.multihead._multihead import _hold_run_offsets


class _Rows(dict):
    def take(self, name, idx):
        return self[name][idx]

    def column(self, name, a, b):
        return self[name][a:b]


def _prep(n: int, runs: int = 1, seed: int = 0, sigma: float = 1.0, C: int = 1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    run = np.repeat(np.arange(runs), n // runs)
    th = 2 * np.pi * 1.3 * t + rng.uniform(0, 2 * np.pi)
    rows = _Rows(t=t, tau=t, theta=th, theta_raw=th)
    return types.SimpleNamespace(
        settings=FinderSettings(),
        keep=np.ones(n, bool),
        rows=rows,
        run=run,
        run_ids=np.arange(runs),
        n_channels=C,
        sigma=np.full(C, sigma),
        consts={"alpha": np.zeros(C)},
        kd=types.SimpleNamespace(project=False),
        ctx=types.SimpleNamespace(n_runs=runs, has_ref=False),
        view_sums=ViewSums(),
    )


def _growing(prep, m: int, a: float, shape: str) -> np.ndarray:
    n = prep.keep.size
    g = np.arange(n) / (n - 1) if shape == "growth" else (np.arange(n) >= 5 * n / 9) * 1.0
    return (a * g * np.sin(m * prep.rows["theta"] + 0.4))[:, None]


def test_a_growing_or_switching_order_the_static_scan_misses_is_located():
    """An order growing from zero (or switching on at 5/9 of the record) whose static fit
    stays below the ``orders`` view's threshold is located at its order, with its shape;
    pure noise gives nothing (the view's false-alarm rate is its own alpha). The static
    threshold counts 10 channels (an SDS record scans its run-mean channels among them)."""
    n, M = 4000, 24
    s = FinderSettings()
    for shape, m, chi2, n_static in (("growth", 7, 26.0, 10), ("switch_on", 11, 45.0, 10)):
        thr_static = chi2_threshold(s.alpha, 2, M * n_static)
        prep = _prep(n, seed=3)
        noise = np.random.default_rng(4).normal(size=(n, 1))
        # amplitude for a full-shape chi-square ``chi2``: the static fit keeps 3/4 of it
        # (growth) or 4/9 (a switch at 5/9)
        a = math.sqrt(2 * chi2 / (n * (1 / 3 if shape == "growth" else 4 / 9)))
        rw = noise + _growing(prep, m, a, shape)
        found = scan_modulated(prep, rw, M, [0], n_static)
        assert [f.where["orders"] for f in found] == [[float(m)]], found
        f = found[0]
        assert f.detail["modulation"] == shape
        assert max(f.detail["static_power_per_channel"]) <= thr_static
        assert f.power > f.detail["threshold_chi2"]
    for seed in range(5):  # noise only
        prep = _prep(n, seed=seed)
        rw = np.random.default_rng(100 + seed).normal(size=(n, 1))
        assert scan_modulated(prep, rw, M, [0], 1) == []


def test_an_order_the_static_scan_finds_is_left_to_it():
    """A strong static order is the ``orders`` view's: this view does not report it too."""
    n = 4000
    prep = _prep(n, seed=5)
    rw = np.random.default_rng(6).normal(size=(n, 1))
    rw[:, 0] += 0.5 * np.sin(9 * prep.rows["theta"]) * (np.arange(n) / n)
    assert scan_modulated(prep, rw, 24, [0], 1) == []


def test_beside_the_static_scan_an_order_is_reported_where_its_shape_is_the_stronger():
    """``beside_static`` (SDS): an order switching on at 5/9 of the record, whose static
    fit passes the ``orders`` view's threshold with a part of its chi-square, is reported
    here too with its switch (the whole of it), so it does not rank below its near-aliases;
    a static order of the same size is left to the ``orders`` view (its switches and growth
    keep less of it and are charged for more tests), and the default leaves both."""
    n, M = 4000, 24
    thr_static = chi2_threshold(FinderSettings().alpha, 2, M)
    prep = _prep(n, seed=11)
    noise = np.random.default_rng(12).normal(size=(n, 1))
    a = math.sqrt(2 * 90.0 / (n * 4 / 9))  # full-shape chi-square 90, static 40
    step = noise + _growing(prep, 11, a, "switch_on")
    assert scan_modulated(prep, step, M, [0], 1) == []
    found = scan_modulated(prep, step, M, [0], 1, beside_static=True)
    assert [f.where["orders"] for f in found] == [[11.0]], found
    f = found[0]
    assert f.detail["modulation"] == "switch_on"
    assert thr_static < max(f.detail["static_power_per_channel"]) < f.power
    static = noise + a * np.sin(11 * prep.rows["theta"] + 0.4)[:, None]
    assert scan_modulated(prep, static, M, [0], 1, beside_static=True) == []


def _base_term(offsets):
    name = "run_angle_offset_rad"
    return types.SimpleNamespace(
        cand=types.SimpleNamespace(name="base"),
        values={"fourier_cos_rad": np.zeros(12), name: np.asarray(offsets, float)},
        free={name: np.ones(len(offsets), bool)},
    )


def test_a_run_zero_pulled_by_a_sign_flip_is_held_at_the_low_orders_alignment():
    """Three runs of one sensor (forward, reverse, forward) share a disk error of orders
    1-5; an order 9 of opposite sign in the reverse run makes a fitted run zero of pi / 9
    (where it flips) the better fit of a static base. The low orders reject that zero: the
    runs' zeros are held at their alignment (0 here); a zero they accept is left free."""
    n, R = 3000, 3
    prep = _prep(n, runs=R, seed=7, sigma=0.5e-6)
    th = prep.rows["theta"]
    rng = np.random.default_rng(8)
    y = sum(4e-6 / m * np.sin(m * th + rng.uniform(0, 6)) for m in range(1, 6))
    y = y + 10e-6 * np.where(prep.run == 1, -1.0, 1.0) * np.sin(9 * th + 0.3)
    prep.y = (y + rng.normal(0, 0.5e-6, n))[:, None]
    wrong = _base_term([-math.pi / 9, 0.0])
    note = _hold_run_offsets([wrong], prep)
    assert note is not None and "[1]" in note
    assert np.all(np.abs(wrong.values["run_angle_offset_rad"]) < 0.01)
    assert not wrong.free["run_angle_offset_rad"].any()
    right = _base_term([0.0005, -0.0003])
    assert _hold_run_offsets([right], prep) is None
    assert right.free["run_angle_offset_rad"].all()


def test_regressors_are_made_orthogonal_to_the_base_model():
    """With the base model's Jacobian (``Prepared.base_jacobian``), a shape's chi-square is
    that of its regressors less what the base spans (the residual has no part there): a
    growing order whose static part the base took is located at the exact projected
    chi-square; read with the raw regressors (no Jacobian) it stays below the threshold
    (issue 41, session 18: 3-6 of 30 chi-square lost on SDS steps)."""
    n, m, C = 600, 5, 1
    prep = _prep(n, runs=n, seed=7, C=C)  # one row per run (SDS run means)
    th = prep.rows["theta"]
    J = np.stack([np.ones(n), np.cos(m * th), np.sin(m * th)], 1)[:, None, :]  # (n, C, p)
    g = np.arange(n) / (n - 1)
    X = np.stack([g * np.cos(m * th), g * np.sin(m * th)], 1)
    rng = np.random.default_rng(8)
    y = rng.normal(size=n) + X @ np.array([0.0, 0.6])
    H = J[:, 0] @ np.linalg.pinv(J[:, 0])
    r = (y - H @ y)[:, None]
    thr = scan_modulated(prep, r, 8, [0], 1)
    assert thr == [], thr  # raw regressors: below the growth family's threshold
    prep.base_jacobian = J
    found = scan_modulated(prep, r, 8, [0], 1)
    assert [f.where["orders"] for f in found] == [[float(m)]], found
    f = found[0]
    assert f.detail["modulation"] in ("growth", "decay")  # the same regressors, projected
    Xp = X - H @ X
    exact = float(r[:, 0] @ Xp @ np.linalg.solve(Xp.T @ Xp, Xp.T @ r[:, 0]))
    assert f.power == pytest.approx(exact, rel=1e-9)
    assert f.power > f.detail["threshold_chi2"]
