"""One entry for the discrepancy finder over every recording kind.

``multihead`` recordings go to the kinematic finder (:mod:`encdesign._diagnose`);
``sds``, ``quadrature`` and ``motion`` recordings to their own finders
(:mod:`encdesign._sds_finder`, :mod:`encdesign._quadrature_finder`,
:mod:`encdesign._motion_finder`). All return the same
JSON contract: ``verdict``, ``rms_before``, ``heldout_rms_before``, ``effects``,
``unexplained`` (see ``docs/diagnose.md``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ._recording import Recording


def diagnose_any(rec: Recording, *, plots: str | Path | None = None) -> dict[str, Any]:
    """Diagnose a recording of any kind; returns the diagnose JSON contract as a dict."""
    if rec.kind == "motion":
        from ._motion_finder import diagnose_motion

        return diagnose_motion(rec, plots=plots)
    if rec.kind == "sds":
        from ._sds_finder import diagnose_sds

        return diagnose_sds(rec, plots=plots)
    if rec.kind == "quadrature":
        from ._quadrature_finder import diagnose_quadrature

        return diagnose_quadrature(rec, plots=plots)
    raise NotImplementedError(f"kind {rec.kind!r} is diagnosed by encdesign._diagnose")
