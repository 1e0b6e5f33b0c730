"""The objective registry of problem files: :data:`PROBLEM_OBJECTIVES` maps each objective
name a problem file may give (``objective = "…"``, ``docs/optimization.md``) to its
:class:`~encdesign.design.ProblemObjective`: variables, model keys and their limits, outputs
and the builder that turns a problem into a JAX function of the variables (the functions of
:mod:`encdesign.design._objectives`). User objectives (``_user``) are looked up beside it.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

from ..physics._layout import (
    check_layout,
    layout_noise_amplification,
)
from ._objectives import (
    TOLERANCE_NAMES,
    TOLERANCE_UNITS,
    EncoderDesign,
    LayoutDesign,
    SDSTolerances,
    Tolerances,
    build_metrics,
    cotangent_sensitivity,
    expected_sensitivity,
    layout_metrics,
    sds_residuals,
    smooth_yield,
    tolerance_cost,
)
from ._spec import ModelLimit, ProblemObjective, ProblemView, VariableInfo

__all__ = ["PROBLEM_OBJECTIVES"]

# ----------------------------------------------------------------------------- registry

_RAD = VariableInfo("rad")
_TOL_VARS = {
    f"sigma_{n}": VariableInfo(TOLERANCE_UNITS[n], lower=0.0, doc=f"std of {n}")
    for n in TOLERANCE_NAMES
}
_TOL_MODEL_KEYS = {f"sigma_{n}": 0.0 for n in TOLERANCE_NAMES}


def _geometry(model: dict[str, Any]) -> dict[str, Any]:
    """The :class:`~encdesign.design.AbstractBuildDesign` keywords of a problem's model."""
    out: dict[str, Any] = {k: model[k] for k in ("radius_m", "tilt_rad", "gap_m")}
    for k in ("max_order", "grating_orders", "axial_orders", "n_angles"):
        out[k] = int(model[k])
    return out


def _design_from(model: dict[str, Any], reference_angle: Any) -> EncoderDesign:
    return EncoderDesign(
        reference_angle_rad=reference_angle, n_heads=int(model["n_heads"]), **_geometry(model)
    )


def _tolerances_from(model: dict[str, Any], x: dict[str, Any]) -> Tolerances:
    return Tolerances(**{n: x.get(f"sigma_{n}", model[f"sigma_{n}"]) for n in TOLERANCE_NAMES})


def _build_sensitivity(problem: ProblemView, discrete: dict[str, Any]):
    m = problem.model
    n_heads = int(discrete.get("n_heads", m["n_heads"]))
    key = jax.random.key(problem.seed)

    def evaluate(x):
        ang = x.get("reference_angle", m["reference_angle_rad"])
        sig = x.get("sigma_placement", m["sigma_placement"])
        if m["n_builds"] > 0 and (float(m["sigma_placement"]) > 0 or "sigma_placement" in x):
            s = expected_sensitivity(
                ang, n_heads, int(m["max_order"]), sig, key=key, n_builds=int(m["n_builds"])
            )
        else:
            s = cotangent_sensitivity(ang, n_heads, int(m["max_order"]))
        return {"sensitivity": s}

    return evaluate


def _build_residual(problem: ProblemView, discrete: dict[str, Any]):
    m = dict(problem.model)
    m.update(discrete)
    key = jax.random.key(problem.seed)
    yt = problem.yield_target
    n_builds = int(yt.n_builds if yt is not None else m["n_builds"])
    q = float(m["percentile"])
    ref = jnp.array([m[f"cost_ref_{n}"] for n in TOLERANCE_NAMES])

    def evaluate(x):
        design = _design_from(m, x.get("reference_angle", m["reference_angle_rad"]))
        tol = _tolerances_from(m, x)
        vals = build_metrics(
            design,
            tol,
            key=key,
            n_builds=n_builds,
            metric=m["metric"],
            chunk_size=int(m["chunk_size"]),
        )
        out = {
            "residual_percentile": jnp.percentile(vals, q),
            "residual_mean": jnp.mean(vals),
            "cost": tolerance_cost(tol.vector(), ref),
        }
        if yt is not None:
            out["yield_smooth"] = smooth_yield(vals, yt.spec, m["smooth_width"] * yt.spec)
            out["yield"] = jnp.mean((vals <= yt.spec).astype(jnp.float64))
        return out

    return evaluate


def _build_cost(problem: ProblemView, discrete: dict[str, Any]):
    inner = _build_residual(problem, discrete)

    def evaluate(x):
        out = inner(x)
        return {"cost": out["cost"], **{k: v for k, v in out.items() if k != "cost"}}

    return evaluate


def _build_sds(problem: ProblemView, discrete: dict[str, Any]):
    m = dict(problem.model)
    m.update(discrete)
    key = jax.random.key(problem.seed)
    tol = SDSTolerances(**{k: float(m[k]) for k in _SDS_TOL_KEYS})

    def evaluate(x):
        vals = sds_residuals(
            int(m["pole_pairs"]),
            int(m["n_sensors"]),
            tol,
            key=key,
            n_builds=int(m["n_builds"]),
            marks_per_rev=int(m["marks_per_rev"]),
            n_phi=int(m["n_phi"]),
        )
        return {"sds_residual": jnp.mean(vals), "sds_residual_max": jnp.max(vals)}

    return evaluate


_SDS_TOL_KEYS = (
    "eccentricity_rad",
    "ellipticity_rad",
    "harmonic_rad",
    "random_rad",
    "speed_ripple",
    "axis_tilt_rad",
)

_DESIGN_MODEL = {
    "radius_m": 0.0254,
    "reference_angle_rad": 0.5,
    "tilt_rad": 0.0,
    "gap_m": 1e-3,
    "n_heads": 3,
    "max_order": 16,
    "grating_orders": 16,
    "axial_orders": 2,
    "n_angles": 128,
    "n_builds": 200,
    "metric": "rms",
    "percentile": 99.0,
    "smooth_width": 0.05,
    "chunk_size": 64,
    **_TOL_MODEL_KEYS,
    **{f"cost_ref_{n}": 0.0 for n in TOLERANCE_NAMES},
}

PROBLEM_OBJECTIVES: dict[str, ProblemObjective] = {
    "cotangent_sensitivity": ProblemObjective(
        name="cotangent_sensitivity",
        doc="noise amplification of self-compensation (mean over placement-error builds)",
        variables={
            "reference_angle": _RAD,
            "sigma_placement": _TOL_VARS["sigma_placement"],
            "n_heads": VariableInfo("1", discrete=True, integer=True, lower=2),
        },
        model={
            "n_heads": 3,
            "max_order": 16,
            "reference_angle_rad": 0.5,
            "sigma_placement": 0.0,
            "n_builds": 64,
        },
        outputs=("sensitivity",),
        build=_build_sensitivity,
        # n_builds = 0: the nominal sensitivity, without placement-error builds
        model_limits={"n_builds": ModelLimit(0, 10_000_000)},
    ),
    "residual": ProblemObjective(
        name="residual",
        doc="percentile of the per-build residual after averaging and self-compensation",
        variables={
            "reference_angle": _RAD,
            **_TOL_VARS,
            "n_heads": VariableInfo("1", discrete=True, integer=True, lower=2),
        },
        model=_DESIGN_MODEL,
        outputs=("residual_percentile", "residual_mean", "cost", "yield_smooth", "yield"),
        build=_build_residual,
    ),
    "tolerance_cost": ProblemObjective(
        name="tolerance_cost",
        doc="cost sum_i c_i ref_i / sigma_i of the tolerances (constrain yield_smooth)",
        variables=dict(_TOL_VARS),
        model=_DESIGN_MODEL,
        outputs=("cost", "residual_percentile", "residual_mean", "yield_smooth", "yield"),
        build=_build_cost,
        requires_yield=True,
    ),
    "sds_residual": ProblemObjective(
        name="sds_residual",
        doc="mean SDS residual over the platform turn (Monte Carlo disks) per pole/sensor",
        variables={
            "pole_pairs": VariableInfo("1", discrete=True, integer=True, lower=1),
            "n_sensors": VariableInfo("1", discrete=True, integer=True, lower=1),
        },
        model={
            "pole_pairs": 6,
            "n_sensors": 2,
            "n_builds": 2,
            "marks_per_rev": 500,
            "n_phi": 16,
            **{k: float(getattr(SDSTolerances(), k)) for k in _SDS_TOL_KEYS},
        },
        outputs=("sds_residual", "sds_residual_max"),
        build=_build_sds,
    ),
}
"""Objectives that problem files can name (``[problem] objective``)."""


def _check_head_angles(start: Any, where: str) -> None:
    check_layout(start, where=where)


def _build_layout(problem: ProblemView, discrete: dict[str, Any]):
    m = dict(problem.model)
    m.update(discrete)
    key = jax.random.key(problem.seed)
    yt = problem.yield_target
    n_builds = int(yt.n_builds if yt is not None else m["n_builds"])
    q = float(m["percentile"])
    ref = jnp.array([m[f"cost_ref_{n}"] for n in TOLERANCE_NAMES])
    default_angles = jnp.asarray(m["head_angles_rad"], dtype=jnp.float64)
    check_layout(default_angles, where=f"{problem.path or problem.name}: model.head_angles_rad")

    def evaluate(x):
        angles = x.get("head_angles", default_angles)
        design = LayoutDesign(head_angles_rad=angles, **_geometry(m))
        tol = _tolerances_from(m, x)
        ms = layout_metrics(
            design, tol, key=key, n_builds=n_builds, metric="ms", chunk_size=int(m["chunk_size"])
        )
        vals = jnp.sqrt(ms) if m["metric"] == "rms" else layout_metrics(
            design, tol, key=key, n_builds=n_builds, metric=m["metric"],
            chunk_size=int(m["chunk_size"]),
        )  # fmt: skip
        _, _, amp = layout_noise_amplification(angles, design.max_order)
        out = {
            "residual_rms": jnp.sqrt(jnp.mean(ms)),
            "residual_percentile": jnp.percentile(vals, q),
            "residual_mean": jnp.mean(vals),
            "noise_amplification": amp,
            "cost": tolerance_cost(tol.vector(), ref),
        }
        if yt is not None:
            out["yield_smooth"] = smooth_yield(vals, yt.spec, m["smooth_width"] * yt.spec)
            out["yield"] = jnp.mean((vals <= yt.spec).astype(jnp.float64))
        return out

    return evaluate


_LAYOUT_MODEL = {
    k: v for k, v in _DESIGN_MODEL.items() if k not in ("reference_angle_rad", "n_heads")
}
_LAYOUT_MODEL["head_angles_rad"] = [0.0, 2.0943951023931953, 4.1887902047863905, 0.3157]

_HEAD_LAYOUT = ProblemObjective(
    name="head_layout",
    doc="RMS residual over builds of a free head layout (least-squares self-compensation)",
    variables={
        "head_angles": VariableInfo(
            "rad",
            lower=-2 * math.pi,
            upper=4 * math.pi,
            size=0,
            check=_check_head_angles,
            doc="azimuth of every head",
        ),
        **_TOL_VARS,
    },
    model=_LAYOUT_MODEL,
    outputs=(
        "residual_rms",
        "residual_percentile",
        "residual_mean",
        "noise_amplification",
        "cost",
        "yield_smooth",
        "yield",
    ),
    build=_build_layout,
)

PROBLEM_OBJECTIVES["head_layout"] = _HEAD_LAYOUT


_SDS_MARK_TOLS = ("eccentricity_rad", "ellipticity_rad", "harmonic_rad", "random_rad")


def _build_sds_layout(problem: ProblemView, discrete: dict[str, Any]):
    from ..physics._sds import equally_spaced

    m = dict(problem.model)
    m.update(discrete)
    key = jax.random.key(problem.seed)
    yt = problem.yield_target
    n_builds = int(yt.n_builds if yt is not None else m["n_builds"])
    pp, ns = int(m["pole_pairs"]), int(m["n_sensors"])
    q = float(m["percentile"])
    ref = jnp.array([float(m[f"cost_ref_{k}"]) for k in _SDS_MARK_TOLS])

    def evaluate(x):
        tol = SDSTolerances(**{k: x.get(k, float(m[k])) for k in _SDS_TOL_KEYS})
        vals = sds_residuals(
            pp,
            ns,
            tol,
            key=key,
            n_builds=n_builds,
            marks_per_rev=int(m["marks_per_rev"]),
            n_phi=int(m["n_phi"]),
            fixed_azimuths_rad=x.get("fixed_azimuths", equally_spaced(ns)),
            moving_azimuths_rad=x.get("moving_azimuths", equally_spaced(ns)),
        )
        sig = jnp.stack([jnp.asarray(getattr(tol, k), dtype=jnp.float64) for k in _SDS_MARK_TOLS])
        out = {
            "sds_residual": jnp.mean(vals),
            "sds_residual_percentile": jnp.percentile(vals, q),
            "sds_residual_max": jnp.max(vals),
            "cost": tolerance_cost(sig, ref),
        }
        if yt is not None:
            out["yield_smooth"] = smooth_yield(vals, yt.spec, m["smooth_width"] * yt.spec)
            out["yield"] = jnp.mean((vals <= yt.spec).astype(jnp.float64))
        return out

    return evaluate


def _check_sensor_azimuths(start: Any, where: str) -> None:
    a = jnp.asarray(start, dtype=jnp.float64).reshape(-1)
    if a.shape[0] >= 2:
        check_layout(a, where=where)


PROBLEM_OBJECTIVES["sds_layout"] = ProblemObjective(
    name="sds_layout",
    doc="SDS residual over the platform turn (mean, percentile, yield) of Monte Carlo builds: "
    "sensor azimuths and mark tolerances continuous, pole pairs and sensors discrete",
    variables={
        "pole_pairs": VariableInfo("1", discrete=True, integer=True, lower=1),
        "n_sensors": VariableInfo("1", discrete=True, integer=True, lower=1),
        "moving_azimuths": VariableInfo(
            "rad", size=0, check=_check_sensor_azimuths, doc="moving sensors' azimuths at phi=0"
        ),
        "fixed_azimuths": VariableInfo(
            "rad", size=0, check=_check_sensor_azimuths, doc="fixed sensors' azimuths"
        ),
        **{
            k: VariableInfo("rad", lower=0.0, doc=f"mark-error tolerance {k}")
            for k in _SDS_MARK_TOLS
        },
    },
    model={
        "pole_pairs": 5,
        "n_sensors": 3,
        "n_builds": 2,
        "marks_per_rev": 500,
        "n_phi": 16,
        "percentile": 99.0,
        "smooth_width": 0.05,
        **{k: float(getattr(SDSTolerances(), k)) for k in _SDS_TOL_KEYS},
        **{f"cost_ref_{k}": float(getattr(SDSTolerances(), k)) for k in _SDS_MARK_TOLS},
    },
    outputs=(
        "sds_residual",
        "sds_residual_percentile",
        "sds_residual_max",
        "cost",
        "yield_smooth",
        "yield",
    ),
    build=_build_sds_layout,
)
