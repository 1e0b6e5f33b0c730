"""The recording kinds the finder diagnoses: :data:`KINDS` maps a recording's ``kind`` to the
kind object (an :class:`~encdesign.diagnose.engine._kind.AbstractKind`) the engine runs it
with. A new kind: its folder under ``kinds/`` and one line here (``docs/DEVELOPING.md``)."""

from __future__ import annotations

from .engine._kind import AbstractKind
from .kinds.motion import MOTION
from .kinds.multihead import MULTIHEAD
from .kinds.quadrature import QUADRATURE
from .kinds.sds import SDS

KINDS: dict[str, AbstractKind] = {
    "multihead": MULTIHEAD,  # several heads on one disk, or one sensor against a reference
    "motion": MOTION,
    "sds": SDS,
    "quadrature": QUADRATURE,
}
"""Recording kind -> the kind object :func:`~encdesign.diagnose.diagnose` runs it with."""
