"""Benchmark: the discrepancy finder on concealed effects, and its model terms vs NumPy.

1. The reading-space model (base multihead model plus every catalog term) evaluated by
   ``encdesign.diagnose._multihead._predict`` (JAX, jit) and by a plain NumPy implementation of the
   same equations in this file: compared (max abs difference, rad) and timed.
2. ``encdesign.diagnose`` on a 4-head, 16,000-sample recording (compilation included:
   the first call in a fresh process), the issue's performance criterion (< 60 s).
3. Optionally (``--conceal``) the full blind benchmark of the study ``conceal-benchmark``
   (44 recordings); its summary is embedded.

    python benchmarks/diagnose.py --json results/bench-diagnose.json [--conceal]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import encdesign
from encdesign.diagnose import _multihead as D
from encdesign.diagnose._conceal import write_concealed


def numpy_predict(p: np.ndarray, prep: D.Prepared) -> np.ndarray:
    """The same model as ``_diagnose._predict``, written with NumPy (rad, (n, H))."""
    lay = prep.layout
    seg = {k: p[s : s + n] for k, (s, n) in lay.segments.items()}
    th, al, R = prep.theta, prep.alpha, prep.radius_m
    H, Rn = lay.n_heads, lay.n_runs
    m = np.arange(1, lay.max_order + 1)
    arg = m[None, None, :] * (th[:, None, None] - (al + seg["d"])[None, :, None])
    out = seg["c"][None, :] + np.sum(seg["a"] * np.cos(arg) + seg["b"] * np.sin(arg), -1)
    mz = np.arange(1, lay.runout_orders + 1)
    z = np.cos(np.outer(th, mz)) @ seg["bt_zc"] + np.sin(np.outer(th, mz)) @ seg["bt_zs"]
    out += np.outer(z, seg["bt_beta"]) / R
    run = prep.run
    wa = seg["wb_nu"][0] * th[:, None] - al[None, :]
    out += (seg["wb_A"][run][:, None] * np.sin(wa) + seg["wb_B"][run][:, None] * np.cos(wa)) / R
    w = 2 * np.pi * seg["vb_f"][0] * prep.t
    C, S = seg["vb_C"].reshape(Rn, H)[run], seg["vb_S"].reshape(Rn, H)[run]
    out += C * np.cos(w)[:, None] + S * np.sin(w)[:, None]
    out += np.outer(np.asarray(prep.data["driver"]), seg["th_k"])
    if lay.grating_lines:
        c = seg["ip"].reshape(4, H)
        ps = prep.psi
        mask = np.asarray(prep.data["psi_mask"])
        out += (
            mask
            * (
                c[0] * np.cos(ps)
                + c[1] * np.sin(ps)
                + c[2] * np.cos(2 * ps)
                + c[3] * np.sin(2 * ps)
            )
            / lay.grating_lines
        )
    width = float(prep.data["width_s"])
    step = 0.5 * (1 + np.tanh(0.5 * (prep.tau - seg["es_t"][0]) / width))
    d = th[:, None] - al[None, :]
    out += step[:, None] * (seg["es_x"][0] * np.sin(d) + seg["es_y"][0] * np.cos(d)) / R
    return out


def main(argv: list[str] | None = None) -> int:
    """Run; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, required=True)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--conceal", action="store_true", help="also run the 44-recording study")
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="bench-diagnose-"))
    rec, truth = write_concealed(
        tmp / "bench16k.toml",
        key=jax.random.key(5),
        effect="beam_tilt_axial",
        samples_per_run=4000,
        speeds_rev_s=(0.6, 1.0, 1.4, 1.8),
    )
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    d = encdesign.diagnose(rec)
    diag_wall = time.perf_counter() - t0
    diag_cpu = time.process_time() - cpu0
    t0 = time.perf_counter()
    encdesign.diagnose(rec)
    diag_warm = time.perf_counter() - t0
    prep = D.prepare(rec)
    lay = prep.layout
    rng = np.random.default_rng(0)
    p = rng.normal(size=lay.size + 1) * 1e-6
    p[prep.idx("d")] = 1e-3
    p[prep.idx("wb_nu")] = 0.4
    p[prep.idx("vb_f")] = 31.0
    p[prep.idx("es_t")] = prep.tau[prep.n // 2]
    p[prep.idx("bt_beta")] = 1e-2
    f = jax.jit(lambda q: D._predict(q, prep.data, lay))
    pj = jnp.asarray(p)
    ref = numpy_predict(p, prep)
    got = np.asarray(f(pj))
    diff = float(np.max(np.abs(got - ref)))
    tj, tn = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        f(pj).block_until_ready()
        tj.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        numpy_predict(p, prep)
        tn.append(time.perf_counter() - t0)
    out = dict(
        machine=dict(platform=platform.platform(), cpus=os.cpu_count(), load_avg=os.getloadavg()),
        model_terms=dict(
            n_samples=prep.n,
            n_heads=lay.n_heads,
            max_abs_diff_rad=diff,
            jax_s=min(tj),
            numpy_s=min(tn),
        ),
        diagnose_16k=dict(
            n_samples=rec.n_rows,
            n_heads=len(rec.head_columns),
            hidden=truth["effect"],
            verdict=d.verdict,
            named=[e.name for e in d.effects],
            wall_s_first_call=diag_wall,
            cpu_s_first_call=diag_cpu,
            wall_s_second_call=diag_warm,
            criterion_s=60.0,
        ),
    )
    if args.conceal:
        from encdesign.cli._main import _load_study

        mod = _load_study("conceal-benchmark")
        sj = tmp / "conceal.json"
        mod.main(["--out", str(tmp / "conceal"), "--json", str(sj), "--no-plots"])
        s = json.loads(sj.read_text())
        s.pop("rows", None)
        out["conceal_benchmark"] = s
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))
    if diff > 1e-15:
        print(f"model terms differ by {diff} rad", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
