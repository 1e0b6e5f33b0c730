"""One entry for the discrepancy finder over every recording kind.

``multihead`` recordings go to the kinematic finder (:mod:`encdesign.diagnose._multihead`);
``sds``, ``quadrature`` and ``motion`` recordings to their own finders
(:mod:`encdesign.diagnose._sds`, :mod:`encdesign.diagnose._quadrature`,
:mod:`encdesign.diagnose._motion`). All return the same
JSON contract: ``verdict``, ``rms_before``, ``heldout_rms_before``, ``effects``,
``unexplained`` (see ``docs/diagnose.md``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..io._recording import Recording


def diagnose_any(rec: Recording, *, plots: str | Path | None = None) -> dict[str, Any]:
    """Diagnose a recording of any kind; returns the diagnose JSON contract as a dict."""
    if rec.kind == "motion":
        from ._motion import diagnose_motion

        return diagnose_motion(rec, plots=plots)
    if rec.kind == "sds":
        from ._sds import diagnose_sds

        return diagnose_sds(rec, plots=plots)
    if rec.kind == "quadrature":
        from ._quadrature import diagnose_quadrature

        return diagnose_quadrature(rec, plots=plots)
    raise NotImplementedError(f"kind {rec.kind!r} is diagnosed by encdesign.diagnose._multihead")
