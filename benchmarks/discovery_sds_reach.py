"""What a view sized to one SDS structure could reach at the finder's level (issue 41, s26).

For each case of :mod:`benchmarks.discovery` (``outside_record(default_rng([S, 0, c, s, 0]),
cls, size, "sds")``, the benchmark's records at ``--seeds 1``), the record is diagnosed and,
on the base model's whitened residual (the one the views read), the truth's own columns are
tested the way a view that knew them would test them:

* ``switch_true``: the truth's order on the truth's sensor (``platform``: on every moving
  sensor) times a switch on at every one of the ``R - 1`` boundaries between runs in time
  order, the best boundary; ``growth_true``: times a linear growth; ``static_true``: static;
  each ``(raw, read against the level without its own columns)`` (the level-out factor
  of :mod:`encdesign.diagnose.kinds.sds._sds_level_out`), 2 dof, projected on the base's
  complement;
* ``switch_max_any``: the best switch over every order the view would scan (one sensor:
  ``1..R M / 2 - 1`` x every sensor; platform: ``1..(R - 1) // 2``) and boundary, with its
  ``(order, sensor, boundary)``;
* ``oracle``: the benchmark's oracle numbers (the true noise, the finder's level over it);
  ``levels``: the finder's run-mean level and its parts;
* ``thr``: thresholds (2 dof, ``alpha`` 1e-3) for libraries of several sizes: the switch at
  ``R - 1`` boundaries with order and sensor known, with the sensor unknown (``M (R - 1)``),
  with the order unknown too, the ``modulated_orders`` view's, the ``common_modulated``
  view's, and discovery's for one term (``discover_alpha`` 0.01).

A case the truth's own test misses at the ``R - 1`` threshold cannot be located by any view
of that shape at the finder's level: its level, not the library, is what stops it::

    python benchmarks/discovery_sds_reach.py --seeds 20261410,7960 --json out.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import discovery as B  # noqa: E402

from encdesign.diagnose._dispatch import diagnose  # noqa: E402
from encdesign.diagnose.engine import _discover as D  # noqa: E402
from encdesign.diagnose.engine import _engine  # noqa: E402
from encdesign.diagnose.engine._views import chi2_threshold  # noqa: E402
from encdesign.diagnose.kinds.sds._sds import sds_limit  # noqa: E402
from encdesign.diagnose.kinds.sds._sds_noise import noise_info  # noqa: E402
from encdesign.simulate._outside import CLASSES, outside_record  # noqa: E402

SIZE_INDEX = {2.0: 0, 5.0: 1, 20.0: 2}


def reach(seed: int, cls: str, size: float) -> dict:
    """The numbers of the module doc for one case."""
    key = [seed, 0, CLASSES.index(cls), SIZE_INDEX[size], 0]
    rec, truth = outside_record(np.random.default_rng(key), cls, size, "sds", 3000)
    B._CAP.clear()
    d = diagnose(rec)
    prep, fitter = B._CAP["base_prep"], B._CAP["base_fitter"]
    keep = np.asarray(prep.keep, bool)
    sig = np.asarray(prep.sigma, float)
    r = (np.asarray(B._CAP["base_resid"], float)[keep] / sig).ravel()
    R, C = int(keep.sum()), sig.size
    M = int(np.asarray(prep.consts["psi_m"]).size)
    J = D._jacobian(prep, fitter, B._CAP["base_terms"])[keep]  # whitened
    U, sv, _ = np.linalg.svd(J.reshape(R * C, -1), full_matrices=False)
    U = U[:, sv > 1e-9 * sv.max()]
    th = np.asarray(prep.rows["theta_eff" if "theta_eff" in prep.rows else "theta"], float)
    th = th[keep]
    rank = np.empty(R, int)
    rank[np.argsort(np.asarray(prep.rows["t"], float)[keep], kind="stable")] = np.arange(R)
    fac = noise_info(prep.ctx).level_factor
    n = int(truth["line"][1])
    k = int(truth["frame"].split("m")[-1]) if truth["frame"].startswith("sensor") else None
    top = sds_limit(prep)

    def chi(nn: int, kk: int | None, w: np.ndarray) -> tuple[float, float]:
        cs = np.stack([np.cos(nn * th), np.sin(nn * th)], -1) * w[:, None]
        X = np.zeros((R, M, 2))
        if kk is None:
            X[:] = cs[:, None, :]
        else:
            X[:, kk] = cs
        Xf = np.zeros((R, C, 2))
        Xf[:, :M] = X / sig[None, :M, None]
        Xf = Xf.reshape(R * C, 2)
        Xf = Xf - U @ (U.T @ Xf)
        Q, s, _ = np.linalg.svd(Xf, full_matrices=False)
        Q = Q[:, s > 1e-8 * s.max()]
        g = float(np.sum((Q.T @ r) ** 2))
        return g, g * (fac(X) if fac is not None else 1.0)

    def best_switch(nn: int, kk: int | None) -> tuple[float, float, int]:
        best = (0.0, 0.0, 0)
        for j in range(1, R):
            g, gf = chi(nn, kk, (rank >= j).astype(float))
            if gf > best[1]:
                best = (g, gf, j)
        return best

    out: dict = {
        "seed": key,
        "class": cls,
        "size": size,
        "verdict": d.verdict,
        "effects": [e["name"] for e in d.effects],
        "order": n,
        "sensor": k,
        "runs": R,
        "sensors": M,
        "switch_true": best_switch(n, k),
        "growth_true": chi(n, k, rank / (R - 1.0)),
        "static_true": chi(n, k, np.ones(R)),
    }
    cands = (
        [(nn, kk) for nn in range(1, top + 1) for kk in range(M)]
        if k is not None
        else [(nn, None) for nn in range(1, (R - 1) // 2 + 1)]
    )
    best_any = (0.0, None)
    for nn, kk in cands:
        _, gf, j = best_switch(nn, kk)
        if gf > best_any[0]:
            best_any = (gf, (nn, kk, j))
    out["switch_max_any"] = best_any
    ora = B._oracle(cls, size, "sds", key, 3000)
    out["oracle"] = {
        q: ora.get(q)
        for q in (
            "oracle_noncentrality",
            "noise_finder_over_true",
            "noise_true_run_means_rad",
            "noise_finder_run_means",
        )
    }
    lv = noise_info(prep.ctx).levels
    out["levels"] = {q: lv.get(q) for q in lv if q.startswith("run_means")}
    a, L = 1e-3, (R - 1) // 2
    out["thr"] = {
        "switch known order and sensor (R-1)": chi2_threshold(a, 2, R - 1),
        "switch known order (M (R-1))": chi2_threshold(a, 2, M * (R - 1)),
        "switch any order (top M 2 (R-1))": chi2_threshold(a, 2, top * M * 2 * (R - 1)),
        "modulated_orders switches": chi2_threshold(a / 2, 2, top * M * 2 * 8),
        "modulated_orders growths": chi2_threshold(a / 2, 2, top * M * 2),
        "common_modulated switches": chi2_threshold(a / 2, 2, 2 * (R - 1) * L),
        "common_modulated growths": chi2_threshold(a / 2, 2, 2 * L),
        "discovery one term": chi2_threshold(0.01, 2, 1),
    }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True, help="comma list of benchmark seeds")
    ap.add_argument("--classes", default="sensor_step,slow_growth,platform_step")
    ap.add_argument("--size", type=float, default=2.0)
    ap.add_argument("--json", default=None, help="JSON lines, one case each")
    a = ap.parse_args(argv)
    _engine.discover = B._capture
    _engine._document = B._capture_document
    f = open(a.json, "w") if a.json else None  # noqa: SIM115 - written case by case
    for s in a.seeds.split(","):
        for cls in a.classes.split(","):
            line = json.dumps(reach(int(s), cls, a.size), default=float)
            print(line, flush=True)
            if f:
                f.write(line + "\n")
                f.flush()
    if f:
        f.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
