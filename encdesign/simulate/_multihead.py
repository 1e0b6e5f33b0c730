"""Multihead bench simulator of a design file: noisy head readings of the design's model at
its ``[[bench.runs]]`` (or at the samples of a measured recording), written as a recording of
kind ``multihead`` (``encdesign simulate DESIGN.toml``, ``docs/design-file.md``).
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import input_error
from ..design._design import Design
from ..io._recording import Recording, load_recording, write_recording
from ..physics._kinematics import EncoderModel, noisy_head_readings

__all__ = ["SIMULATE_CHUNK", "simulate_bench", "simulate_recording"]


def simulate_bench(
    design: Design,
    *,
    key: jax.Array,
    t_s: np.ndarray | None = None,
    theta_rad: np.ndarray | None = None,
    run: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Bench columns of a design: ``t``, ``run``, ``theta_ref``, ``h0 … h{H-1}``.

    By default the samples are the design's ``[[bench.runs]]``. Passing ``t_s``,
    ``theta_rad`` (and optionally ``run``) instead simulates at those samples (for
    example those of a measured recording). Readings include the design's read noise.

    Args:
        design: the validated design.
        key: ``jax.random`` key for the read noise.
        t_s: sample times, s; theta_rad: true shaft angles, rad; run: run ids.

    Returns:
        Column name -> 1-D numpy array (SI units).
    """
    if t_s is None:
        parts = [r.times_and_angles() for r in design.runs]
        t_s = np.concatenate([p[0] for p in parts])
        theta_rad = np.concatenate([p[1] for p in parts])
        run = np.concatenate([np.full(len(p[0]), i, dtype=np.int64) for i, p in enumerate(parts)])
    elif theta_rad is None:
        raise input_error("simulate_bench", "t_s without theta_rad", "theta_rad with t_s")
    if run is None:
        run = np.zeros(len(t_s), dtype=np.int64)
    readings = _simulate_chunked(design.model, np.asarray(theta_rad), np.asarray(t_s), key)
    if not np.all(np.isfinite(readings)):
        raise input_error(
            str(design.path or "design"),
            "the simulation produced non-finite readings",
            "a geometry in which every beam meets the disk",
        )
    cols: dict[str, np.ndarray] = {"t": np.asarray(t_s, float), "run": np.asarray(run)}
    cols["theta_ref"] = np.asarray(theta_rad, float)
    for k in range(design.n_heads):
        cols[f"h{k}"] = readings[:, k]
    return cols


@jax.jit
def _simulate_jit(model: EncoderModel, theta: jax.Array, t: jax.Array, key: jax.Array):
    return noisy_head_readings(model, theta, t, key=key)


SIMULATE_CHUNK = 65_536
"""Samples simulated per compiled call: memory stays bounded by the chunk, not the bench."""


def _simulate_chunked(
    model: EncoderModel, theta: np.ndarray, t: np.ndarray, key: jax.Array
) -> np.ndarray:
    """Noisy head readings ``(n, H)`` in chunks of :data:`SIMULATE_CHUNK` samples.

    A bench of at most one chunk uses ``key`` as is; longer benches draw chunk ``i``'s noise
    from ``fold_in(key, i)``. The last chunk is padded to the chunk length so that every
    call reuses one compilation.
    """
    n = theta.shape[0]
    if n <= SIMULATE_CHUNK:
        return np.asarray(_simulate_jit(model, jnp.asarray(theta), jnp.asarray(t), key))
    out = None
    for i, a in enumerate(range(0, n, SIMULATE_CHUNK)):
        b = min(n, a + SIMULATE_CHUNK)
        th, tt = theta[a:b], t[a:b]
        if b - a < SIMULATE_CHUNK:
            pad = SIMULATE_CHUNK - (b - a)
            th = np.concatenate([th, np.full(pad, th[-1])])
            tt = np.concatenate([tt, np.full(pad, tt[-1])])
        r = np.asarray(
            _simulate_jit(model, jnp.asarray(th), jnp.asarray(tt), jax.random.fold_in(key, i))
        )
        if out is None:
            out = np.empty((n, r.shape[1]))
        out[a:b] = r[: b - a]
    return out


def simulate_recording(
    design: Design,
    out: str | os.PathLike,
    *,
    seed: int = 0,
    like: str | os.PathLike | None = None,
    compress: bool = False,
    parquet: bool = False,
) -> Recording:
    """Simulate a bench and write it as a multihead recording (atomically).

    Args:
        design: the validated design.
        out: output TOML path (the CSV goes beside it).
        seed: PRNG seed of the read noise.
        like: optional multihead recording whose samples (``t``, ``run``, ``theta_ref``)
            are reused instead of the design's ``[[bench.runs]]``; its head count must
            match the design's.
        compress: write ``.csv.gz``.
        parquet: write the table as Parquet (``.parquet``).

    Returns:
        The written :class:`~encdesign.Recording`.
    """
    key = jax.random.key(seed)
    provenance: dict[str, Any] = {"simulated_by": "encdesign simulate", "seed": seed}
    if design.path is not None:
        provenance["design"] = str(design.path)
    if like is not None:
        rec = load_recording(like)
        where = str(rec.path)
        if rec.kind != "multihead":
            raise input_error(where, f"kind '{rec.kind}'", "a multihead recording for --like")
        n_rec = len(rec.head_columns)
        if n_rec != design.n_heads:
            raise input_error(
                where,
                f"{n_rec} heads but the design has {design.n_heads}",
                "the same head count in recording and design",
            )
        if "theta_ref" not in rec.columns:
            raise input_error(where, "no column 'theta_ref'", "a reference angle to sample at")
        cols = simulate_bench(
            design,
            key=key,
            t_s=rec.columns["t"],
            theta_rad=rec.columns["theta_ref"],
            run=rec.runs,
        )
        provenance["samples_from"] = where
    else:
        cols = simulate_bench(design, key=key)
    desc = design.description or "simulated bench recording"
    return write_recording(
        out,
        "multihead",
        cols,
        encoder=design.encoder_table(),
        description=desc,
        provenance=provenance,
        compress=compress,
        parquet=parquet,
        source=str(design.path or "design"),
    )
