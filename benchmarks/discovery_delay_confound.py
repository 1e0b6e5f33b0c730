"""Is ``sensor_delay_step`` confounded with an SDS one-sensor growth or step (issue 41,
session 32)? The fit of each structure on the other's truth, at the record's true noise.

For an SDS case of ``benchmarks/discovery.py`` (seed base, class, size: the benchmark's own
seed list ``[seed, 0, class index, size index, 0]``), the case is diagnosed as the benchmark
does (:func:`discovery.run_case`, which gives the true term's thresholds), then, in the
oracle's coordinates (the structure's exact part ``mu`` and the noise's true levels per
component, whitened, the base model's columns projected out: ``lambda = |mu'|^2``):

* ``delay_share``: the largest share of ``lambda`` that one sensor-delay step takes (a step
  from run ``r`` on, one free delay per moving sensor: the catalog effect's form), and its
  ``delay_first_run``;
* ``truth_left_beside_delay``: the noncentrality the true model (its frame and modulation:
  a growth with its static part, or a step at the truth's run) still takes once that delay
  step is fitted with it, against ``threshold_true_raw_chi2`` / ``threshold_locate_chi2``;
* ``delay_left_beside_truth``: what the delay step takes beside the true model.

The two are confounded (the catalog may keep its name by the issue's discipline) where the
truth beside the delay step takes no more than its thresholds; a false name where it takes
more (the delay step is a part of the structure, the truth is not a part of the delay step)::

    python benchmarks/discovery_delay_confound.py --case 20261473:sensor_step:5 --json F
"""

from __future__ import annotations

import argparse
import json
import math

import discovery as B
import numpy as np

from encdesign.diagnose.engine import _discover as D
from encdesign.diagnose.engine import _engine
from encdesign.diagnose.kinds.sds._sds_noise import _sensor_helmert
from encdesign.simulate._outside import CLASSES, outside_record

_PHI: dict = {}


def _share(m: np.ndarray, X: np.ndarray) -> float:
    """The share of ``|m|^2`` in the span of the columns ``X``."""
    Q, s, _ = np.linalg.svd(X, full_matrices=False)
    Q = Q[:, s > 1e-9 * s.max()]
    return float(np.sum((Q.T @ m) ** 2) / (m @ m))


def case(seed: int, cls: str, size: float, rows: int = 3000) -> dict:
    """The numbers of the module doc for one case."""
    import encdesign.simulate._sds as S

    orig = S.sds_bench_columns

    def capture(design, phis, *a, **kw):  # the runs' platform angles (rad)
        _PHI["phi"] = np.asarray(phis, float)
        return orig(design, phis, *a, **kw)

    S.sds_bench_columns = capture
    try:
        key = [seed, 0, CLASSES.index(cls), B.SIZES.index(size), 0]
        res = B.run_case(cls, size, "sds", key, rows)
        y_s = outside_record(np.random.default_rng(key), cls, size, "sds", rows, noise=False)
        y_0 = outside_record(np.random.default_rng(key), cls, 0.0, "sds", rows, noise=False)
        _, truth = outside_record(np.random.default_rng(key), cls, size, "sds", rows)
    finally:
        S.sds_bench_columns = orig
    prep, fitter = B._CAP["base_prep"], B._CAP["base_fitter"]
    keep = np.asarray(prep.keep, bool)
    ys, y0 = (B._prepared_y(r[0], prep.settings) for r in (y_s, y_0))
    mu, eps = (ys - y0)[keep], (np.asarray(prep.y, float) - ys)[keep]
    sig = np.asarray(prep.sigma, float)
    C, M, R = sig.size, int(np.asarray(prep.consts["psi_m"]).size), mu.shape[0]
    T = np.kron(np.eye(C // M), _sensor_helmert(M))
    e = eps @ T
    e = e - e.mean(0)
    group = 2 * (np.arange(C) >= M) + (np.arange(C) % M == 0)
    true = np.array(
        [
            math.sqrt(float(np.sum(e[:, group == g] ** 2)) / ((R - 1) * int(np.sum(group == g))))
            for g in group
        ]
    )
    w = 1.0 / true
    J = D._jacobian(prep, fitter, B._CAP["base_terms"])[keep] * sig[None, :, None]
    Jw = np.einsum("ncp,cd->ndp", J, T) * w[None, :, None]
    U, sv, _ = np.linalg.svd(Jw.reshape(R * C, -1), full_matrices=False)
    U = U[:, sv > 1e-9 * sv.max()]

    def vec(P: np.ndarray) -> np.ndarray:  # an (R, C) pattern, whitened, off the base
        v = ((P @ T) * w).ravel()
        return v - U @ (U.T @ v)

    def on(k: int, col: np.ndarray) -> np.ndarray:  # a pattern of sensor k's run means
        P = np.zeros((R, C))
        P[:, k] = col
        return vec(P)

    m = vec(mu)
    lam = float(m @ m)
    n, k = truth["line"][1], int(truth["frame"].split("m")[1])
    i, phi = np.arange(R), _PHI["phi"]
    g = i / (R - 1) if cls == "slow_growth" else (i >= truth["run"]).astype(float)
    cols = [g * np.cos(n * phi), g * np.sin(n * phi)]
    if cls == "slow_growth":  # a growth from zero: the growth and its static part
        cols += [np.cos(n * phi), np.sin(n * phi)]
    Xt = np.stack([on(k, c) for c in cols], 1)
    best = (-1.0, 0, None)
    for r in range(1, R):
        Xd = np.stack([on(j, (i >= r).astype(float)) for j in range(M)], 1)
        s = _share(m, Xd)
        if s > best[0]:
            best = (s, r, Xd)
    s_d, r_d, Xd = best
    both = _share(m, np.concatenate([Xd, Xt], 1)) * lam
    return {
        "case": f"{seed}:{cls}:{size:g}",
        "verdict": res["verdict"],
        "effects": res["effects"],
        "truth": {"frame": truth["frame"], "order": n, "run": truth.get("run")},
        "lambda": lam,
        "structure_in_truths_span": _share(m, Xt),
        "delay_share": s_d,
        "delay_first_run": r_d,
        "truth_left_beside_delay": both - s_d * lam,
        "delay_left_beside_truth": both - _share(m, Xt) * lam,
        "threshold_true_raw_chi2": res.get("threshold_true_raw_chi2"),
        "threshold_locate_chi2": res.get("threshold_locate_chi2"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", action="append", required=True, help="SEED:CLASS:SIZE")
    ap.add_argument("--rows", type=int, default=3000)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    _engine.discover = B._capture
    _engine._document = B._capture_document
    out = []
    for c in a.case:
        seed, cls, size = c.split(":")
        r = case(int(seed), cls, float(size), a.rows)
        r["confounded"] = not (
            r["truth_left_beside_delay"]
            > max(r["threshold_true_raw_chi2"], r["threshold_locate_chi2"])
        )
        out.append(r)
        print(json.dumps(r), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"args": vars(a), "cases": out}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
