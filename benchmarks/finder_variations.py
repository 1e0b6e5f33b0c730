"""Benchmark: the finder on recordings from a generator written apart from the concealed
benchmark (``encdesign.simulate._conceal_bench``), over wider ranges.

``--set clean``: clean multihead / sensor records, 1-7 heads (1 = a sensor with
``theta_ref``), 400-20,000 samples, 1-3 runs, noise 5e-8..3e-5 rad, 0.5-63 turns, one or
both directions, 30 Hz-3 kHz, half of them with 30 % sampling jitter, 30 % with a gap, disk
error orders 1..M (M 3-11) of 3-300x the noise, per-run zeros of every head and of the
reference. ``--set high``: the same with M 13-20. ``--set effects``: one effect at 5x the
noise (vibration, direction_hysteresis, scale_error, eccentricity_shift, bearing_wobble).
Prints one line per record and the rate (consistent, or named exactly right; a clean record
whose every named effect is reported confounded with the base's own order, nothing left
unexplained, counts right: the record cannot tell them, and the report says so)::

    python benchmarks/finder_variations.py --set clean --seed 5 --n 30 [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from encdesign import Recording
from encdesign.diagnose._dispatch import diagnose

EFFECTS = [
    "vibration",
    "direction_hysteresis",
    "scale_error",
    "eccentricity_shift",
    "bearing_wobble",
]


def clean_record(rng, orders_lo: int = 3, orders_hi: int = 12):
    H = int(rng.integers(1, 8))
    sensor = H == 1
    n = int(rng.choice([400, 1500, 5000, 20000]))
    R = int(rng.integers(1, 4))
    noise = float(10 ** rng.uniform(-7.3, -4.5))
    turns = float(10 ** rng.uniform(-0.3, 1.8))
    both = bool(rng.random() < 0.4)
    rate = float(10 ** rng.uniform(1.5, 3.5))
    nr = n // R
    ts, ths, runs = [], [], []
    for r in range(R):
        dt = 1 / rate
        t = np.cumsum(dt * (1 + 0.3 * rng.uniform(-1, 1, nr) * (rng.random() < 0.5)))
        if rng.random() < 0.3:  # a gap
            i = int(rng.integers(nr // 4, 3 * nr // 4))
            t[i:] += 50 * dt
        sp = turns * 2 * np.pi / (t[-1] - t[0]) * (1 + 0.3 * r)
        if both:
            half = nr // 2
            th = np.where(
                np.arange(nr) < half, sp * (t - t[0]), sp * (t[half] - t[0]) - sp * (t - t[half])
            )
        else:
            th = sp * (t - t[0])
        th = th + rng.uniform(0, 6.3)
        ts.append(t + (r * (t[-1] + 5)))
        ths.append(th)
        runs.append(np.full(nr, r))
    t = np.concatenate(ts)
    th = np.concatenate(ths)
    run = np.concatenate(runs)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.2, 6.1, H - 1))])
    M = int(rng.integers(orders_lo, orders_hi))
    err = np.zeros((t.size, H))
    amp0 = noise * 10 ** rng.uniform(0.5, 2.5)
    for m in range(1, M + 1):
        a = amp0 / m ** rng.uniform(0.5, 1.5)
        ph = rng.uniform(0, 6.3)
        for k in range(H):
            err[:, k] += a * np.sin(m * (th - alpha[k]) + ph)
    y = th[:, None] + err + rng.normal(0, noise, err.shape)
    ref = th.copy()
    for r in range(R):
        m_ = run == r
        y[m_] += rng.integers(-3, 4, H) * 2 * np.pi + rng.uniform(-3, 3, H)
        ref[m_] += rng.uniform(-3, 3)
    cols = {"t": t, "run": run}
    use_ref = sensor or rng.random() < 0.5
    if use_ref:
        cols["theta_ref"] = ref
    for k in range(H):
        cols[f"h{k}"] = y[:, k]
    enc = {"head_angles_deg": [float(np.degrees(a)) for a in alpha]}
    if sensor:
        enc["sensor"] = str(rng.choice(["magnetic", "resolver", "capacitive", "optical"]))
        enc["signal_periods_per_rev"] = int(rng.choice([1, 2, 7, 16, 2048]))
    else:
        enc["optical_radius_m"] = float(rng.uniform(0.01, 0.1))
        enc["grating_lines"] = int(rng.choice([1000, 4096, 36000]))
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    desc = dict(H=H, n=n, R=R, noise=noise, turns=turns, both=both, rate=rate, M=M, ref=use_ref)
    return Recording("multihead", meta, cols), desc


def even_runs(R: int, nr: int, rate: float, path, rng):
    """``R`` runs of ``nr`` evenly spaced samples at ``rate`` (Hz), each followed by a 2 s
    pause: the run's shaft angle ``path(r, t)`` (rad, ``t`` from 0 s within the run) plus a
    random start in [0, 6.3) rad drawn from ``rng`` after it. Returns the concatenated time
    (s), angle (rad) and run index."""
    ts, ths, runs = [], [], []
    for r in range(R):
        t = np.arange(nr) / rate
        ths.append(path(r, t) + rng.uniform(0, 6.3))
        ts.append(t + r * (t[-1] + 2))
        runs.append(np.full(nr, r))
    return np.concatenate(ts), np.concatenate(ths), np.concatenate(runs)


def effect_record(rng, eff: str):
    sensor = eff in ("direction_hysteresis", "scale_error")
    H = 1 if sensor else int(rng.integers(2, 7))
    n = int(rng.choice([1500, 5000]))
    R = 2
    noise = float(10 ** rng.uniform(-7, -5))
    turns = (
        float(10 ** rng.uniform(0.8, 1.5))
        if eff in ("vibration", "bearing_wobble")
        else float(10 ** rng.uniform(0.3, 1.2))
    )
    both = sensor
    rate = float(10 ** rng.uniform(2, 3.3))
    nr = n // R

    def path(r: int, t: np.ndarray) -> np.ndarray:
        sp = turns * 2 * np.pi / t[-1] * (1 + 0.5 * r)
        if both:
            half = nr // 2
            return np.where(np.arange(nr) < half, sp * t, sp * t[half] - sp * (t - t[half]))
        return sp * t

    t, th, run = even_runs(R, nr, rate, path, rng)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.3, 6.0, H - 1))])
    err = np.zeros((t.size, H))
    for m in range(1, int(rng.integers(3, 10))):
        a = noise * 10 ** rng.uniform(0.5, 2) / m
        ph = rng.uniform(0, 6.3)
        err += a * np.sin(m * (th[:, None] - alpha[None, :]) + ph)
    A = 5 * noise
    om = np.gradient(th, t)
    if eff == "vibration":
        f = rate * rng.uniform(0.05, 0.45)
        err += (
            A
            * rng.uniform(0.5, 1, H)
            * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 6.3, (R, H))[run])
        )
    elif eff == "direction_hysteresis":
        err += A * np.sign(om)[:, None]
    elif eff == "scale_error":
        err += (2 * A / np.ptp(th)) * (th - th.mean())[:, None]
    elif eff == "eccentricity_shift":
        ts_ = t[0] + (t[-1] - t[0]) * rng.uniform(0.3, 0.7)
        err += (
            (t >= ts_)[:, None]
            * 1.5
            * A
            * np.sin(th[:, None] - alpha[None, :] + rng.uniform(0, 6.3))
        )
    elif eff == "bearing_wobble":
        nu = rng.uniform(0.3, 0.7)
        err += (
            1.5
            * A
            * np.sin(nu * th[:, None] + rng.uniform(0, 6.3, R)[run][:, None] - alpha[None, :])
        )
    y = th[:, None] + err + rng.normal(0, noise, err.shape) + rng.uniform(-3, 3, (R, H))[run]
    cols = {"t": t, "run": run}
    use_ref = sensor or rng.random() < 0.5
    if use_ref:
        cols["theta_ref"] = th + rng.uniform(-3, 3, R)[run]
    for k in range(H):
        cols[f"h{k}"] = y[:, k]
    enc = {"head_angles_deg": [float(np.degrees(a)) for a in alpha]}
    if sensor:
        enc["sensor"] = "optical"
        enc["signal_periods_per_rev"] = 4096
    else:
        enc["optical_radius_m"] = 0.03
        enc["grating_lines"] = 4096
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), dict(
        eff=eff, H=H, n=n, noise=noise, turns=round(turns, 1), rate=round(rate), ref=use_ref
    )


def own_confounded(d: dict) -> bool:
    """A clean record reported as an identifiability conflict that includes the truth: every
    named effect confounded with the base model's own order (one sensor whose signal period
    falls inside its disk error's orders, ``base_order_<m>``), and nothing else left."""
    return (
        bool(d["effects"])
        and not d["unexplained"]
        and all(
            any(c["name"].startswith("base_order_") for c in e.get("confounded_with") or [])
            for e in d["effects"]
        )
    )


def main(argv: list[str] | None = None) -> int:
    """Run one set; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("clean", "high", "effects"), default="clean")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    rows = []
    for i in range(args.n):
        if args.set == "effects":
            eff = EFFECTS[i % len(EFFECTS)]
            rec, desc = effect_record(np.random.default_rng([args.seed, 99, i]), eff)
        else:
            eff = None
            lo, hi = (13, 21) if args.set == "high" else (3, 12)
            rec, desc = clean_record(np.random.default_rng([args.seed, i]), lo, hi)
        t0 = time.perf_counter()
        d = diagnose(rec).doc
        names = [e["name"] for e in d["effects"]]
        ok = names == [eff] if eff else (d["verdict"] == "consistent" or own_confounded(d))
        rows.append(
            dict(i=i, ok=ok, verdict=d["verdict"], names=names, s=time.perf_counter() - t0, **desc)
        )
        print(
            i,
            "ok " if ok else "BAD",
            d["verdict"],
            names,
            f"{rows[-1]['s']:.1f} s",
            desc,
            flush=True,
        )
    rate = sum(r["ok"] for r in rows) / max(len(rows), 1)
    print(
        f"{args.set} seed {args.seed}: {sum(r['ok'] for r in rows)} / {len(rows)} right", flush=True
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                {"set": args.set, "seed": args.seed, "rate": rate, "rows": rows},
                f,
                indent=1,
                default=float,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
