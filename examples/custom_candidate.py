"""A candidate effect of your own: `encdesign diagnose REC --candidates custom_candidate.py`.

A drive belt turns a pulley at 2.7 times the shaft speed and shakes one head's mount: an
error at the non-integer shaft order 2.7, with its own amplitude and phase per head. The
catalog does not have it; registering it lets the finder name it, fit it with standard
errors, and prove it on held-out data like any catalog effect (``docs/diagnose.md``).
"""

import jax.numpy as jnp

from encdesign.diagnose import Candidate, Param

BELT_RATIO = 2.7  # pulley turns per shaft turn (known from the drive's design)


def belt_ripple(p, x):
    """Error (rad) per sample and head: ``A_k cos(2.7 theta) + B_k sin(2.7 theta)``."""
    arg = BELT_RATIO * x["theta"][:, None]
    return p["cos_rad"][None, :] * jnp.cos(arg) + p["sin_rad"][None, :] * jnp.sin(arg)


CANDIDATES = [
    Candidate(
        name="belt_ripple",
        fn=belt_ripple,
        params=(
            Param("cos_rad", "rad", "channels", description="cos amplitude per head"),
            Param("sin_rad", "rad", "channels", description="sin amplitude per head"),
        ),
        signature=("spectrum",),  # it shows as a line at order 2.7
        kinds=("multihead",),
        explanation="A drive belt at 2.7x shaft speed shakes the head mount (user-defined).",
    )
]
