"""encdesign: differentiable design, optimisation and diagnosis of precision angular encoders.

All quantities are SI (metres, seconds, radians) unless a name says otherwise (``_deg``,
``_urad``, ``_arcsec``). float64 is switched on at import: micro-radian effects on top of
radian-sized angles need it.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._errors import EncdesignInputError as EncdesignInputError
from ._recording import (
    Recording as Recording,
    load_recording as load_recording,
    write_recording as write_recording,
)

# --- kinematics, encoder theorem, self-compensation (issue 2) ---

# --- shifted-delta-sum timing model (issue 3) ---

# --- quadrature signal layer (issue 6) ---

__version__ = "0.1.0"
