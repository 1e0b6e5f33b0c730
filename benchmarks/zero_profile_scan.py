"""Diagnosis (issue 44 C): the change time scanned with the later runs' angle zeros profiled
jointly with the step, against the scan at zeros chosen by the base alone.

Records of ``tests/helpers.shift_arcs_record`` (record ``i`` of seed ``S`` from
``default_rng([S, 44, 23, i])``; ``i = -1``: ``tests/test_order_step_part_turn.shift_record(S)``).
On the raw head-projected readings (the head mean removed per row), the base is a constant
per run and head and the disk orders ``1..M`` (the truth's ``M``) at the head-mean shaft
angle plus each later run's zero; the step is ``sin, cos (theta - alpha_k)`` from a change
row on. Per record:

* the base-alone zeros (the best of a grid of ``NZ`` points per later run) and the scan's
  best change row at them (what a scan after the base's fit sees);
* the profile: at each of ``NT`` change rows the least chi-square over the zero grid, then
  at its ``TOP`` best rows and at the truth's row the zeros refined by a shrinking
  coordinate search; its best row and chi-square, the one at the truth's row, and the
  zeros' errors (fitted - truth, rad).

No other effect of the record is modelled: where the record holds others (chi-square far
above ``rows x (H - 1)``) the scan here is not the finder's::

    python benchmarks/zero_profile_scan.py 7820 0,1,2,3,4,5,6,7,8,9
    python benchmarks/zero_profile_scan.py 7622 -1
"""

from __future__ import annotations

import itertools
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).parent))
from helpers import WHERE, shift_arcs_record  # noqa: E402
from run_zero_pull import wrap  # noqa: E402

NZ = 24
"""Grid points of a later run's zero over one turn."""
NT = 256
"""Change rows of the coarse scan."""
TOP = 4
"""Best coarse change rows whose zeros are refined."""
ROUNDS = 20
"""Rounds of the coordinate search (its step shrinks by ``SHRINK`` per round)."""
SHRINK = 0.6


def scan(y, run, al, M: int, zeros: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """The chi-square of :func:`fit` with the step from each change row ``cand``."""
    return fit(y, run, al, M, zeros, cand)[1]


def fit(y, run, al, M: int, zeros: np.ndarray, cand: np.ndarray) -> tuple[float, np.ndarray]:
    """Chi-square (not whitened) of the base alone, and of the base with the step from each
    change row ``cand`` (rows in time order: runs end to end), the base refitted jointly
    (suffix sums of the step's products with an orthonormal basis of the base columns)."""
    n, H = y.shape
    R = int(run.max()) + 1
    th = y.mean(1) + np.concatenate([[0.0], zeros])[run]
    P = y - y.mean(1, keepdims=True)
    cols = [
        ((run == r)[:, None] & (np.arange(H) == k)[None, :]).astype(float)
        for r in range(R)
        for k in range(H)
    ]
    arg = th[:, None] - al[None, :]
    for m in range(1, M + 1):
        cols += [np.sin(m * arg), np.cos(m * arg)]
    A = np.stack([(b - b.mean(1, keepdims=True)).ravel() for b in cols], 1)
    Q = np.linalg.qr(A)[0]
    p = P.ravel()
    r = p - Q @ (Q.T @ p)
    X = np.stack([np.sin(arg), np.cos(arg)], 2)
    X = X - X.mean(1, keepdims=True)  # (n, H, 2)
    QX = np.einsum("nhk,nhi->nki", Q.reshape(n, H, -1), X)
    SQX = np.cumsum(QX[::-1], 0)[::-1]
    SXX = np.cumsum(np.einsum("nhi,nhj->nij", X, X)[::-1], 0)[::-1]
    SXr = np.cumsum(np.einsum("nhi,nh->ni", X, r.reshape(n, H))[::-1], 0)[::-1]
    G = SXX[cand] - np.einsum("cki,ckj->cij", SQX[cand], SQX[cand])
    g = SXr[cand]
    chi2 = float(r @ r)
    if cand.size == 0:
        return chi2, np.zeros(0)
    return chi2, chi2 - np.einsum("ci,ci->c", g, np.linalg.solve(G, g[..., None])[..., 0])


def one(seed: int, i: int) -> None:
    """Print the base-alone scan and the profiled scan of one record."""
    if i < 0:
        rec, truth = shift_arcs_record(np.random.default_rng([seed, 44, 22]), WHERE[seed % 3])
    else:
        rec, truth = shift_arcs_record(np.random.default_rng([seed, 44, 23, i]), WHERE[i % 3])
    t0 = time.process_time()
    H, M, s2 = truth["desc"]["H"], truth["desc"]["M"], truth["desc"]["noise"] ** 2
    y = np.stack([np.asarray(rec.columns[f"h{k}"], float) for k in range(H)], 1)
    run = np.asarray(rec.columns["run"], int)
    t = np.asarray(rec.columns["t"], float)
    al = np.radians(np.asarray(rec.meta["encoder"]["head_angles_deg"], float))
    n, R = y.shape[0], int(run.max()) + 1
    if not np.array_equal(np.lexsort((t, run)), np.arange(n)):
        raise ValueError("rows are not in time order")
    margin = max(20, n // 50)
    ct = int(
        np.flatnonzero((run > truth["run"]) | ((run == truth["run"]) & (t >= truth["t_s"])))[0]
    )
    cand = np.append(np.unique(np.linspace(margin, n - margin, NT).astype(int)), ct)
    z0 = np.asarray(truth["run_zeros_rad"], float)
    grid = np.linspace(-np.pi, np.pi, NZ, endpoint=False)
    zs = [np.array(z) for z in itertools.product(grid, repeat=R - 1)]
    tab = np.stack([scan(y, run, al, M, z, cand) for z in zs])  # (zeros, rows)
    # the base alone: its best zeros, then the scan there (the truth's row left out)
    base = [fit(y, run, al, M, z, np.zeros(0, int))[0] for z in zs]
    zb = zs[int(np.argmin(base))]
    jb = int(cand[int(np.argmin(scan(y, run, al, M, zb, cand[:-1])))])
    refined = {}
    for j in [*np.argsort(tab[:, :-1].min(0))[:TOP], cand.size - 1]:
        z, step = zs[int(np.argmin(tab[:, j]))].copy(), grid[1] - grid[0]
        for _ in range(ROUNDS):
            for k in range(R - 1):
                trial = [z + d * step * (np.arange(R - 1) == k) for d in (0.0, 1.0, -1.0)]
                z = trial[int(np.argmin([scan(y, run, al, M, w, cand[[j]])[0] for w in trial]))]
            step *= SHRINK
        refined[int(cand[j])] = (scan(y, run, al, M, z, cand[[j]])[0] / s2, wrap(z - z0))
    jp = min(refined, key=lambda k: refined[k][0])

    def row(c: int) -> str:
        return f"run {run[c]} t {t[c]:.4f}"

    print(
        f"{seed}/{i} H={H} R={R} truth {row(ct)} ({truth['t_s']:.4f}) | base-alone zeros "
        f"(err {np.round(wrap(zb - z0), 2).tolist()} rad): best {row(jb)} | profiled: best "
        f"{row(jp)} chi2 {refined[jp][0]:.1f} (zero err {np.round(refined[jp][1], 3).tolist()}), "
        f"at the truth {refined[ct][0]:.1f} (zero err {np.round(refined[ct][1], 3).tolist()}); "
        f"rows x (H - 1) {n * (H - 1)} | {time.process_time() - t0:.1f} s CPU",
        flush=True,
    )


def main(argv: list[str] | None = None) -> int:
    """``SEED i,j,...``; returns 0."""
    args = sys.argv[1:] if argv is None else argv
    for i in map(int, args[1].split(",")):
        one(int(args[0]), i)
    return 0


if __name__ == "__main__":
    sys.exit(main())
