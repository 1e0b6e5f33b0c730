"""Benchmark: multihead records of less than one turn without a reference (issue 44, the
short-arc misses of the ``high`` variation set): 2-4 heads, 0.3-0.95 turns covered (one
direction, or forward and back), disk error orders 1..M (M 3-20) of 3-300x the noise,
noise 5e-8..1e-5 rad, 30 Hz-3 kHz, 1 or 2 runs, clean (``--set clean``: right when
``consistent``) or with one effect 8-15x the noise (``--set effects``: right when exactly
that effect is named: vibration or an eccentricity shift)::

    python benchmarks/short_arcs.py --set clean --seed 6000 --n 10 [--only 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from finder_variations import even_runs

from encdesign import Recording
from encdesign.diagnose._dispatch import diagnose

EFFECTS = ["vibration", "eccentricity_shift"]


def short_record(rng, eff: str | None = None):
    """One record of the class and its description."""
    H = int(rng.integers(2, 5))
    n = int(rng.choice([400, 1500, 5000]))
    R = int(rng.integers(1, 3))
    noise = float(10 ** rng.uniform(-7.3, -5))
    turns = float(rng.uniform(0.3, 0.95))
    both = bool(rng.random() < 0.4)
    rate = float(10 ** rng.uniform(1.5, 3.5))
    nr = n // R

    def path(r: int, t: np.ndarray) -> np.ndarray:
        if both:
            half = nr // 2
            return turns * 2 * np.pi * np.where(np.arange(nr) < half, t / t[half], 2 - t / t[half])
        return turns * 2 * np.pi * (t / t[-1])

    t, th, run = even_runs(R, nr, rate, path, rng)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.3, 6.0, H - 1))])
    M = int(rng.integers(3, 21))
    err = np.zeros((t.size, H))
    amp0 = noise * 10 ** rng.uniform(0.5, 2.5)
    for m in range(1, M + 1):
        a = amp0 / m ** rng.uniform(0.5, 1.5)
        err += a * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6.3))
    A = float(rng.uniform(8, 15)) * noise
    L = int(rng.choice([1000, 4096, 36000]))
    if eff == "vibration":
        f = rate * rng.uniform(0.05, 0.45)
        err += A * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 6.3, (R, H))[run])
    elif eff == "eccentricity_shift":
        ts_ = t[0] + (t[-1] - t[0]) * rng.uniform(0.3, 0.7)
        err += (t >= ts_)[:, None] * A * np.sin(th[:, None] - alpha[None, :] + rng.uniform(0, 6.3))
    y = th[:, None] + err + rng.normal(0, noise, err.shape)
    y += rng.uniform(-3, 3, (R, H))[run]
    cols = {"t": t, "run": run}
    for k in range(H):
        cols[f"h{k}"] = y[:, k]
    enc = {
        "head_angles_deg": [float(np.degrees(a)) for a in alpha],
        "optical_radius_m": 0.03,
        "grating_lines": L,
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    desc = dict(
        eff=eff, H=H, n=n, R=R, noise=noise, turns=round(turns, 2), both=both, rate=round(rate), M=M
    )
    return Recording("multihead", meta, cols), desc


def main(argv: list[str] | None = None) -> int:
    """Run one set; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("clean", "effects"), default="clean")
    ap.add_argument("--seed", type=int, default=6000)
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--only", type=int, default=None, help="run only record i")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    rows = []
    for i in range(args.n) if args.only is None else [args.only]:
        eff = EFFECTS[i % len(EFFECTS)] if args.set == "effects" else None
        rec, desc = short_record(np.random.default_rng([args.seed, 44, i]), eff)
        t0 = time.perf_counter()
        d = diagnose(rec).doc
        names = [e["name"] for e in d["effects"]]
        ok = names == [eff] if eff else d["verdict"] == "consistent"
        rows.append(dict(i=i, ok=ok, verdict=d["verdict"], names=names, **desc))
        print(
            i,
            "ok " if ok else "BAD",
            d["verdict"],
            names,
            f"{time.perf_counter() - t0:.1f} s",
            desc,
            flush=True,
        )
    n_ok = sum(r["ok"] for r in rows)
    print(f"{args.set} seed {args.seed}: {n_ok} / {len(rows)} right", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"set": args.set, "seed": args.seed, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
