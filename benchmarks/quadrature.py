"""Benchmark: quadrature signal synthesis + ellipse fit + correction, JAX vs plain NumPy.

Both implementations do the same physics on the same number of samples: signals of eq. 1
(offsets, amplitude ratio, phase error, white noise) along a path, the direct least-squares
ellipse fit (Halir-Flusser form of Fitzgibbon's method), the Heydemann correction and the
unwrapped arctangent position. Reports samples per second (best of ``--repeat`` runs after
one warm-up/compile run) and checks that both fits agree.

    .venv/bin/python benchmarks/quadrature.py --json results/bench-quadrature.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import encdesign as ed
from encdesign.io._study import write_json

PITCH_M = 20e-6
ERR = {"offset_a": 0.04, "offset_b": -0.03, "amplitude_ratio": 0.95, "phase_error_rad": 0.05}
AMP = 0.5
NOISE = 0.003


# ----------------------------------------------------------------------------- NumPy


def numpy_pipeline(x_m: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    psi = 2 * np.pi * x_m / PITCH_M
    sa = AMP * (ERR["offset_a"] + ERR["amplitude_ratio"] * np.sin(psi + ERR["phase_error_rad"]))
    sb = AMP * (ERR["offset_b"] + np.cos(psi))
    sa = sa + NOISE * rng.standard_normal(sa.shape)
    sb = sb + NOISE * rng.standard_normal(sb.shape)
    # direct least-squares ellipse (Halir & Flusser), normalised coordinates
    ma, mb, da, db = sa.mean(), sb.mean(), sa.std(), sb.std()
    u, w = (sa - ma) / da, (sb - mb) / db
    s = np.zeros((6, 6))
    chunk = 1 << 16
    for i in range(0, u.size, chunk):
        uu, ww = u[i : i + chunk], w[i : i + chunk]
        d = np.stack([uu * uu, uu * ww, ww * ww, uu, ww, np.ones_like(uu)], axis=1)
        s += d.T @ d
    s1, s2, s3 = s[:3, :3], s[:3, 3:], s[3:, 3:]
    t = -np.linalg.solve(s3, s2.T)
    c1inv = np.array([[0.0, 0.0, 0.5], [0.0, -1.0, 0.0], [0.5, 0.0, 0.0]])
    _, vecs = np.linalg.eig(c1inv @ (s1 + s2 @ t))
    v = np.real(vecs)
    a1 = v[:, np.argmax(4 * v[0] * v[2] - v[1] ** 2)]
    q = np.concatenate([a1, t @ a1])
    q = q / np.linalg.norm(q) * np.sign(q[0])
    a, b, c, dd, e, f = q
    den = 4 * a * c - b * b
    x0, y0 = (b * e - 2 * c * dd) / den, (b * dd - 2 * a * e) / den
    sphi = -b / (2 * np.sqrt(a * c))
    k = -(f + 0.5 * (dd * x0 + e * y0)) / (1 - sphi**2)
    params = np.array(
        [ma + da * x0, mb + db * y0, da * np.sqrt(k / a), db * np.sqrt(k / c), np.arcsin(sphi)]
    )
    # Heydemann correction and unwrapped position
    uu = (sa - params[0]) / params[2]
    ww = (sb - params[1]) / params[3]
    sin_psi = (uu - ww * np.sin(params[4])) / np.cos(params[4])
    pos = PITCH_M / (2 * np.pi) * np.unwrap(np.arctan2(sin_psi, ww))
    return pos, params


# ----------------------------------------------------------------------------- JAX


def make_jax_pipeline(n: int):
    errors = ed.SignalErrors(**ERR)

    @jax.jit
    def run(x_m, key):
        sa, sb = ed.synthesize_signals(
            x_m, PITCH_M, errors, amplitude=AMP, noise_std=NOISE, key=key
        )
        fit = ed.fit_ellipse(sa, sb, method="direct", throw=False, chunk_size=1 << 16)
        pos = ed.physics.position_from_signals_m(sa, sb, PITCH_M, fit.params)
        p = fit.params
        return pos, jnp.stack([p.offset_a, p.offset_b, p.amplitude_a, p.amplitude_b, p.phase_rad])

    return run


def timed(fn, repeat: int) -> tuple[float, object]:
    out = fn()  # warm-up (JIT compile for JAX)
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, default=None, help="write the results here")
    p.add_argument("--samples", type=int, default=1_000_000)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)
    n = args.samples
    x = np.linspace(0.0, n / 50 * PITCH_M, n)  # 50 samples per signal period
    xj = jnp.asarray(x)
    run = make_jax_pipeline(n)
    key = jax.random.PRNGKey(0)

    def jax_call():
        pos, par = run(xj, key)
        pos.block_until_ready()
        return np.asarray(pos), np.asarray(par)

    t_jax, (pos_j, par_j) = timed(jax_call, args.repeat)
    t_np, (pos_n, par_n) = timed(lambda: numpy_pipeline(x, 0), args.repeat)
    err_j = float(np.sqrt(np.mean((pos_j - x) ** 2)))
    err_n = float(np.sqrt(np.mean((pos_n - x) ** 2)))
    res = {
        "benchmark": "quadrature",
        "samples": n,
        "device": str(jax.devices()[0]),
        "jax_s": t_jax,
        "numpy_s": t_np,
        "jax_samples_per_s": n / t_jax,
        "numpy_samples_per_s": n / t_np,
        "speedup_jax_over_numpy": t_np / t_jax,
        "fitted_params_jax": par_j.tolist(),
        "fitted_params_numpy": par_n.tolist(),
        "max_param_difference": float(np.max(np.abs(par_j - par_n))),
        "rms_position_error_after_correction_m": {"jax": err_j, "numpy": err_n},
    }
    print(json.dumps(res, indent=2))
    if args.json is not None:
        write_json(args.json, res)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
