"""An objective a user writes: an encoder on a shaft with bearing runout and a cable keep-out.

This module is the example of ``docs/optimization.md`` ("Objective functions you write"). A
problem file names it as ``objective = "mount_objective:keepout_layout"`` (this directory on
``PYTHONPATH``) or, once a package registers it under the entry-point group
``encdesign.objectives``, by its registered name.

The user's own physics: three or more read heads must stay out of a cable keep-out sector
(centre ``keepout_center_rad``, half width ``keepout_half_width_rad``), and the bearing's
radial runout (a model setting, m) decentres the disk like eccentricity. The objective is the
cost of the head-placement tolerance (``ref / sigma``: tighter costs more) plus a smooth
penalty for heads inside the keep-out sector; the RMS residual after self-compensation over
Monte Carlo builds (encdesign's ``layout_metrics``, builds drawn from ``key``) is a second
output, which the problem file constrains to the accuracy spec.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax.nn import softplus

import encdesign
from encdesign.objectives import LayoutDesign, Tolerances, layout_metrics, tolerance_cost


@encdesign.objective_function(
    variables={
        "head_angles": encdesign.variable("rad", lower=-6.3, upper=12.6, size=0),
        "sigma_placement": encdesign.variable("rad", lower=1e-6, upper=1e-3, start=1e-4),
        "n_builds": encdesign.variable("1", values=[8, 16, 32]),
    },
    outputs=("score", "residual_rms_rad", "keepout_penalty", "cost"),
    doc="placement-tolerance cost of a free head layout with a cable keep-out sector",
    model={
        "radius_m": 0.0254,
        "runout_m": 2e-6,
        "grating_rad": 5e-6,
        "noise_rad": 2e-7,
        "keepout_center_rad": 3.1416,
        "keepout_half_width_rad": 0.5,
        "placement_ref_rad": 1e-4,
    },
)
def keepout_layout(x, discrete, model, key):
    """Placement-tolerance cost and RMS residual of a free head layout with a keep-out."""
    angles = x["head_angles"]
    sig_p = x["sigma_placement"]
    design = LayoutDesign(
        radius_m=model["radius_m"],
        head_angles_rad=angles,
        max_order=4,
        grating_orders=4,
        axial_orders=1,
        n_angles=32,
    )
    tol = Tolerances(
        eccentricity=model["runout_m"],
        placement=sig_p,
        grating=model["grating_rad"],
        noise=model["noise_rad"],
    )
    ms = layout_metrics(design, tol, key=key, n_builds=int(discrete["n_builds"]), metric="ms")
    rms = jnp.sqrt(jnp.mean(ms))
    # angular distance of each head from the keep-out centre, wrapped to [0, pi]
    d = jnp.abs(jnp.angle(jnp.exp(1j * (angles - model["keepout_center_rad"]))))
    inside = softplus((model["keepout_half_width_rad"] - d) / 0.02) * 0.02
    penalty = jnp.sum(inside**2) / model["keepout_half_width_rad"] ** 2
    cost = tolerance_cost(jnp.stack([sig_p]), jnp.array([model["placement_ref_rad"]]))
    score = cost + 100.0 * penalty
    return {"score": score, "residual_rms_rad": rms, "keepout_penalty": penalty, "cost": cost}
