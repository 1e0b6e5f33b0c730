"""Discovery's change times (``engine/_discover_lines.locate_steps``, issue 41): on an SDS
record the change point of a ``step`` term is where the term itself, as the library fits it,
takes the most chi-square."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from encdesign.diagnose import FinderSettings
from encdesign.diagnose.engine._discover_lines import Line, locate_steps

GOLDEN = np.pi * (3.0 - np.sqrt(5.0))
"""The golden angle (rad): the SDS bench's platform positions, one per run."""


def _sds_prep(R: int, M: int, C: int) -> SimpleNamespace:
    """What :func:`locate_steps` reads of a prepared SDS record: ``R`` runs (one row each,
    the platform at ``k`` golden angles), ``M`` moving sensors (the first ``M`` channels),
    ``C`` channels, unit noise, ``phi_ref`` (no projection on the sensors' differences)."""
    tau = 0.7 * np.arange(R)  # s
    return SimpleNamespace(
        n=R,
        n_channels=C,
        keep=np.ones(R, bool),
        rows={"theta": GOLDEN * np.arange(R), "t": tau, "tau": tau},
        sigma=np.ones(C),
        settings=FinderSettings(),
        ctx=SimpleNamespace(kind="sds"),
        consts={"psi_m": 2 * np.pi * np.arange(M) / M, "proj": 0.0},
        kd=SimpleNamespace(project=False),
    )


def _platform_step_chi2(
    prep: SimpleNamespace, resid: np.ndarray, J: np.ndarray, m: int, M: int, p: int
) -> float:
    """Chi-square (by least squares on every value) that a platform order ``m`` switched on
    from row ``p`` (one cos / sin pair on every moving sensor) takes from ``resid`` beside
    the catalog columns ``J`` (n, C, p)."""
    th = prep.rows["theta"]
    on = np.arange(prep.n) >= p
    X = np.zeros((prep.n, prep.n_channels, 2))
    X[:, :M, 0] = (np.cos(m * th) * on)[:, None]
    X[:, :M, 1] = (np.sin(m * th) * on)[:, None]
    y, Jf = resid.ravel(), J.reshape(-1, J.shape[2])
    A = np.concatenate([X, J], 2).reshape(-1, 2 + J.shape[2])
    r0 = y - Jf @ np.linalg.lstsq(Jf, y, rcond=None)[0]
    r1 = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
    return float(r0 @ r0 - r1 @ r1)


def test_sds_step_is_placed_where_the_frames_step_term_takes_most():
    """A platform order 7 switching on at run 9 of 24 golden-angle positions (3 moving
    sensors, 1.6 noise units: about 40 chi-square), the catalog holding each moving sensor's
    offset: the change point is where the platform ``step`` term takes the most chi-square,
    the run the truth switches on in on every draw. The scan before session 36 (each
    sensor its own step, the constant line projected out: on 24 positions that constant
    takes most of an order switching on) placed it at run 16 and run 2 on two of these 8
    draws (the benchmark's ``platform_step`` 2x on 20261499: order 5 from run 9 placed at
    run 18, where the platform step took 22.8 chi-square against 45.7 at run 8)."""
    R, M, C, m, on_from = 24, 3, 5, 7, 9
    prep = _sds_prep(R, M, C)
    th = prep.rows["theta"]
    J = np.zeros((R, C, M))  # the catalog model: each moving sensor's offset
    for k in range(M):
        J[:, k, k] = 1.0
    got = []
    for seed in range(8):
        resid = np.random.default_rng(seed).standard_normal((R, C))
        resid[on_from:, :M] += 1.6 * np.cos(m * th[on_from:] + 0.4)[:, None]
        st = locate_steps(prep, resid, [Line("order", float(m))], [], J)[0]
        assert st is not None and st["n_tests"] == R - 3 and st["located_by"] == "scan"
        chi2 = [_platform_step_chi2(prep, resid, J, m, M, p) for p in range(2, R - 1)]
        got.append((st["row"], 2 + int(np.argmax(chi2))))
    assert all(row == best == on_from for row, best in got), got
