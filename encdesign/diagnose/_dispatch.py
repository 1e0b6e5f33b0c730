"""One entry for the discrepancy finder over every recording kind: :func:`diagnose`.

``multihead`` (including one sensor against a reference), ``motion``, ``sds`` and
``quadrature`` recordings all go through the engine (:mod:`encdesign.diagnose._engine`) with
their kind (:mod:`encdesign.diagnose._multihead`, :mod:`encdesign.diagnose._motion`,
:mod:`encdesign.diagnose._sds`, :mod:`encdesign.diagnose._quadrature`); every diagnosis
follows one contract
(``diagnosis.schema.json``).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .._errors import DiagnosisError, input_error
from .._usercode import user_module_items
from ..io._recording import Recording, load_recording
from ._candidates import Candidate
from ._settings import FinderSettings

ENGINE_KINDS = ("multihead", "motion", "sds", "quadrature")


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """A diagnosis: the JSON document (``doc``) plus what the plots need.

    Attributes:
        doc: the diagnosis document (``docs/diagnose.md``, ``diagnosis.schema.json``).
        status: ``"ok"`` or why a fit did not converge.
    """

    doc: dict[str, Any]
    status: str = "ok"
    plot_data: Any = None

    @property
    def verdict(self) -> str:
        """``consistent``, ``missing_physics`` or ``unexplained``."""
        return self.doc["verdict"]

    @property
    def effects(self) -> list[dict]:
        """Named effects, most important first."""
        return self.doc["effects"]

    @property
    def unexplained(self) -> list[dict]:
        """Located structure no effect explains."""
        return self.doc["unexplained"]

    def __getitem__(self, key: str) -> Any:
        return self.doc[key]

    def to_json(self) -> dict[str, Any]:
        """The JSON document."""
        return self.doc


def load_candidates(path: str | os.PathLike) -> tuple[Candidate, ...]:
    """User candidates from a Python file defining ``CANDIDATES`` (a sequence of
    :class:`~encdesign.diagnose.Candidate`)."""
    p = Path(path)
    if not p.is_file():
        raise input_error(f"--candidates {p}", "no such file", "a Python file")
    spec = importlib.util.spec_from_file_location(f"encdesign_user_candidates_{p.stem}", p)
    mod = importlib.util.module_from_spec(spec)
    return user_module_items(  # the user's file and functions run under the guard
        f"--candidates {p}",
        lambda: (spec.loader.exec_module(mod), mod)[1],  # type: ignore[union-attr]
        "CANDIDATES",
        Candidate,
        ("fn", "applies", "start", "plausible", "derived"),
    )


def diagnose(
    recording: Recording | str | os.PathLike,
    *,
    max_order: int | None = None,
    max_effects: int = 3,
    candidates: Sequence[Candidate] = (),
    verbose: bool = False,
    plots: str | os.PathLike | None = None,
    throw: bool = False,
    settings: FinderSettings | None = None,
) -> Diagnosis:
    """Diagnose a recording of any kind.

    Args:
        recording: a :class:`~encdesign.Recording` or the path of its TOML file.
        max_order: highest order of the base model (default: the kind's default, capped at
            what the record resolves); beyond what the record resolves it is refused.
        max_effects: most candidate effects to name.
        candidates: the user's own candidate effects (added to the kind's catalog).
        verbose: a progress bar on stderr.
        plots: folder for PNG figures.
        throw: raise ``RuntimeError`` when a fit did not converge (else ``status`` says so).
        settings: the finder's decision thresholds (:class:`FinderSettings`; default: the
            tuned defaults).

    Raises:
        EncdesignInputError: a recording that cannot be diagnosed.
    """
    rec = recording if isinstance(recording, Recording) else load_recording(recording)
    if rec.kind not in ENGINE_KINDS:
        raise input_error(
            "kind", f"no finder for recording kind {rec.kind!r}", f"one of {ENGINE_KINDS}"
        )
    from ._engine import run_engine

    opts = dict(
        max_order=max_order,
        max_effects=max_effects,
        extra_candidates=candidates,
        verbose=verbose,
        settings=settings,
    )
    if rec.kind == "quadrature":
        from ._quadrature import run_quadrature

        doc = run_quadrature(rec, **opts)
    else:
        if rec.kind == "multihead":
            from ._multihead import MULTIHEAD as kind
        elif rec.kind == "sds":
            from ._sds import SDS as kind
        else:
            from ._motion import MOTION as kind
        doc = run_engine(kind, rec, **opts)
    plot_data = doc.pop("_plot")
    d = Diagnosis(doc, doc["status"], plot_data)
    if plots is not None:
        from ._plots import engine_plots

        doc["plots"] = [str(p) for p in engine_plots(d, plots)]
        if rec.kind == "quadrature":
            from ._quadrature import quadrature_plots

            doc["plots"] += [str(p) for p in quadrature_plots(d, plots)]
    if throw and d.status != "ok":
        raise DiagnosisError(f"diagnose: {d.status}")
    return d
