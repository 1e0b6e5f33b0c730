"""The one ``sds`` bench simulator: edge times of every sensor, one run per platform angle.

:func:`sds_bench_columns` is the simulator (``physics.edge_times`` per run, every sensor's
edges merged in time order, the columns of a recording of kind ``sds``,
``docs/recording-format.md``); :func:`simulate_sds_recording` writes its output as a
recording, and the concealed ``sds`` benches (:mod:`encdesign.simulate._conceal_sds`) call it
with an error model per run and a hook on the exact edge times. Runs follow each other in
time, :data:`RUN_SPACING_REVS` revolutions beyond the simulated ones apart (so drifts
continue across runs). The readout (edge times into φ) is
:func:`encdesign.diagnose.sds_readings_from_recording`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import input_error
from ..io._recording import Recording, write_recording
from ..physics._sds import SDSDesign, edge_times, validate_design
from ..physics._sds_errors import SDSErrors

__all__ = ["RUN_SPACING_REVS", "sds_bench_columns", "sds_encoder_table", "simulate_sds_recording"]

RUN_SPACING_REVS = 2
"""Idle revolutions between two runs (the platform moves): run ``i`` starts at revolution
``i * (n_revs + 1 + RUN_SPACING_REVS)`` of the motor's clock. Two, as the concealed benchmark
was built and scored with (its drift and partial-effect truths are computed on this time
axis); the plain simulator had one, which no test or figure depended on."""

_edge_times_jit = jax.jit(edge_times, static_argnums=(2,), static_argnames=("n_newton",))

PAD_TERMS = 4
"""The bearing-runout components and axial-runout orders of an error model are padded with
zero terms to a multiple of this many (at least this many) before the edge times are
compiled (:func:`padded_errors`): runs and benches whose models differ only in how many
such terms they have (a clean run beside a wobbling or a tilted one) then share one
compiled program instead of one each (2-5 s of compiling per program)."""


def padded_errors(errors: SDSErrors) -> SDSErrors:
    """``errors`` with zero-size terms appended (:data:`PAD_TERMS`): bearing components of
    amplitude 0 (ratio 0, phase 0) and axial-runout orders with coefficients 0. The same
    physics and, term by term, the same arithmetic: each added term contributes an exact
    zero (``0 · sin(·)``, ``0 · cos(·)``) after the existing ones, so the edge times are
    bit-equal (``tests/test_sds.py``)."""

    def pad(a: jax.Array) -> jax.Array:
        n = int(a.shape[0])
        size = max(PAD_TERMS, -(-n // PAD_TERMS) * PAD_TERMS)
        return jnp.concatenate([a, jnp.zeros(size - n, dtype=a.dtype)])

    return dataclasses.replace(
        errors,
        axial_runout_cos_m=pad(errors.axial_runout_cos_m),
        axial_runout_sin_m=pad(errors.axial_runout_sin_m),
        bearing_amplitude_m=pad(errors.bearing_amplitude_m),
        bearing_ratio=pad(errors.bearing_ratio),
        bearing_phase_rad=pad(errors.bearing_phase_rad),
    )


EdgeHook = Callable[[int, float, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def sds_bench_columns(
    design: SDSDesign,
    phi_rad: Sequence[float] | np.ndarray,
    n_revs: int,
    errors: SDSErrors | Sequence[SDSErrors],
    *,
    key: jax.Array,
    n_newton: int = 2,
    edge_hook: EdgeHook | None = None,
) -> dict[str, np.ndarray]:
    """Simulate the edge times of every sensor, one run per platform angle (the columns).

    Args:
        design: the instrument.
        phi_rad: platform angles, one per run, rad (written as ``phi_ref`` mod 2 pi).
        n_revs: complete readings wanted per run (>= 1); ``n_revs + 1`` revolutions are
            simulated (the first one, where the sensors' windows do not start together, is
            not a complete reading).
        errors: the error physics, one for all runs or one per run.
        key: ``jax.random`` key; run ``i`` uses ``fold_in(key, i)`` (jitter).
        n_newton: Newton iterations for the edge times.
        edge_hook: ``hook(i, phi, fixed, moving) -> (fixed, moving)`` applied to run ``i``'s
            edge times (s, shapes ``(F, R, N)`` and ``(M, R, N)``) before they are merged, for
            effects outside the error model (the concealed benches).

    Returns:
        Columns ``run``, ``phi_ref`` (rad), ``sensor`` (``f0…``, ``m0…``), ``mark``, ``t`` (s).
    """
    if isinstance(n_revs, bool) or not isinstance(n_revs, int) or n_revs < 1:
        raise input_error("n_revs", f"got {n_revs!r}", "an integer >= 1")
    phis = np.atleast_1d(np.asarray(phi_rad, dtype=float))
    per_run = not isinstance(errors, SDSErrors)
    if per_run and len(errors) != phis.size:
        raise input_error("errors", f"{len(errors)} error models", f"one or {phis.size}")
    n_marks = design.marks_per_rev
    names = [f"f{i}" for i in range(design.n_fixed)] + [f"m{i}" for i in range(design.n_moving)]
    cols: dict[str, list[np.ndarray]] = {c: [] for c in ("run", "phi_ref", "sensor", "mark", "t")}
    for i, phi in enumerate(phis):
        f, m = _edge_times_jit(
            design,
            jnp.asarray(phi),
            n_revs + 1,
            padded_errors(errors[i] if per_run else errors),
            key=jax.random.fold_in(key, i),
            first_rev=jnp.asarray(i * (n_revs + 1 + RUN_SPACING_REVS), float),
            n_newton=n_newton,
        )
        f, m = np.array(f), np.array(m)  # writable copies
        if edge_hook is not None:
            f, m = edge_hook(i, float(phi), f, m)
        times = np.concatenate([f, m], axis=0)  # (S, R, N)
        s_count, r_count, _ = times.shape
        t = times.reshape(-1)
        order = np.argsort(t, kind="stable")
        cols["t"].append(t[order])
        cols["sensor"].append(np.repeat(np.asarray(names), r_count * n_marks)[order])
        cols["mark"].append(np.tile(np.arange(n_marks), s_count * r_count)[order])
        cols["run"].append(np.full(t.size, i, dtype=np.int64))
        cols["phi_ref"].append(np.full(t.size, float(np.mod(phi, 2 * np.pi))))
    # one column at a time, each run's pieces freed as soon as they are joined
    return {k: np.concatenate(cols.pop(k)) for k in list(cols)}


def sds_encoder_table(design: SDSDesign, clock_period_s: float) -> dict[str, Any]:
    """The ``[encoder]`` table of an ``sds`` recording of ``design`` (angles in degrees)."""
    deg = 180.0 / math.pi
    encoder: dict[str, Any] = {
        "marks_per_rev": design.marks_per_rev,
        "fixed_sensor_angles_deg": [float(x) * deg for x in np.asarray(design.fixed_azimuths_rad)],
        "moving_sensor_angles_deg": [
            float(x) * deg for x in np.asarray(design.moving_azimuths_rad)
        ],
        "pole_pairs": design.pole_pairs,
        "stator_coils": design.stator_coils,
        "commutation_states": design.commutation_states,
    }
    if float(clock_period_s) > 0:
        encoder["clock_hz"] = 1.0 / float(clock_period_s)
    return encoder


def simulate_sds_recording(
    path: str | os.PathLike,
    design: SDSDesign,
    phi_rad: Any,
    n_revs: int,
    errors: SDSErrors | None = None,
    *,
    key: jax.Array | None = None,
    description: str | None = None,
    compress: bool = False,
    parquet: bool = False,
    n_newton: int = 2,
) -> Recording:
    """Simulate a bench run and write it as an ``sds`` recording (TOML + CSV).

    Each platform angle is one run: ``n_revs + 1`` revolutions of every sensor, all
    sensors' edges merged in time order (:func:`sds_bench_columns`).

    Args:
        path: output TOML path (the CSV goes beside it; written atomically).
        design, errors: instrument and error physics.
        phi_rad: platform angles, one per run, rad.
        n_revs: complete readings wanted per run (>= 1).
        key: ``jax.random`` key for jitter (``None``: no jitter).
        description: free text for the TOML.
        compress: write ``.csv.gz``.
        parquet: write the table as Parquet (``.parquet``).
        n_newton: Newton iterations for the edge times.

    Returns:
        The :class:`~encdesign.Recording` as written.
    """
    errors = SDSErrors() if errors is None else errors
    validate_design(design, errors)
    if isinstance(n_revs, bool) or not isinstance(n_revs, int) or n_revs < 1:
        raise input_error("simulate_sds_recording n_revs", f"got {n_revs!r}", ">= 1")
    key = jax.random.PRNGKey(0) if key is None else key  # jitter_s = 0: no effect
    data = sds_bench_columns(design, phi_rad, n_revs, errors, key=key, n_newton=n_newton)
    return write_recording(
        path,
        "sds",
        data,
        encoder=sds_encoder_table(design, float(errors.clock_period_s)),
        description=description or "simulated shifted-delta-sum bench run (encdesign)",
        provenance={"simulated_by": "encdesign.simulate_sds_recording", "n_revs": n_revs},
        compress=compress,
        parquet=parquet,
    )
