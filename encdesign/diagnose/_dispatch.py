"""One entry for the discrepancy finder over every recording kind: :func:`diagnose`.

``multihead`` (including one sensor against a reference), ``motion`` and ``sds`` recordings go
through the engine (:mod:`encdesign.diagnose._engine`) with their kind
(:mod:`encdesign.diagnose._multihead`, :mod:`encdesign.diagnose._motion`,
:mod:`encdesign.diagnose._sds`); ``quadrature`` recordings still go to their own finder
(:mod:`encdesign.diagnose._quadrature`), whose JSON is brought to the same contract
(``diagnosis.schema.json``).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .._errors import input_error
from ..io._recording import Recording, load_recording
from ._candidates import Candidate

ENGINE_KINDS = ("multihead", "motion", "sds")


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
    try:
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
    except Exception as ex:  # the user's file: report it as bad input
        raise input_error(f"--candidates {p}", f"cannot be imported ({ex!r})") from ex
    cands = getattr(mod, "CANDIDATES", None)
    if cands is None or not all(isinstance(c, Candidate) for c in cands):
        raise input_error(
            f"--candidates {p}", "no CANDIDATES sequence of Candidate", "CANDIDATES = [...]"
        )
    return tuple(cands)


def diagnose(
    recording: Recording | str | os.PathLike,
    *,
    max_order: int | None = None,
    max_effects: int = 3,
    candidates: Sequence[Candidate] = (),
    verbose: bool = False,
    plots: str | os.PathLike | None = None,
    throw: bool = False,
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

    Raises:
        EncdesignInputError: a recording that cannot be diagnosed.
    """
    rec = recording if isinstance(recording, Recording) else load_recording(recording)
    if rec.kind in ENGINE_KINDS:
        from ._engine import run_engine

        if rec.kind == "multihead":
            from ._multihead import MULTIHEAD as kind
        elif rec.kind == "sds":
            from ._sds import SDS as kind
        else:
            from ._motion import MOTION as kind
        doc = run_engine(
            kind,
            rec,
            max_order=max_order,
            max_effects=max_effects,
            extra_candidates=candidates,
            verbose=verbose,
        )
        plot_data = doc.pop("_plot")
        if rec.kind == "sds":
            from ._sds import finish_sds

            doc = finish_sds(doc)
        d = Diagnosis(doc, doc["status"], plot_data)
        if plots is not None:
            from ._plots import engine_plots

            doc["plots"] = [str(p) for p in engine_plots(d, plots)]
    else:
        if candidates:
            raise input_error(
                "candidates",
                f"user candidates are not supported for kind {rec.kind!r} yet",
                "a multihead or motion recording",
            )
        from ._quadrature import diagnose_quadrature

        doc = diagnose_quadrature(rec, plots=plots)
        doc = conform(doc, rec)
        d = Diagnosis(doc, doc.get("status", "ok"))
    if throw and d.status != "ok":
        raise RuntimeError(f"diagnose: {d.status}")
    return d


def _unit_of(name: str) -> str:
    for suffix, unit in (
        ("_rad", "rad"),
        ("_m", "m"),
        ("_s", "s"),
        ("_hz", "Hz"),
        ("_arcsec", "arcsec"),
        ("_urad", "urad"),
    ):
        if name.endswith(suffix):
            return unit
    return "1"


def conform(doc: dict[str, Any], rec: Recording) -> dict[str, Any]:
    """Bring a finder's JSON that is not (yet) from the engine to the common contract:
    every effect gets ``delta_bic``, ``collinearity``, ``notes``, ``params`` as given; the
    document gets ``goodness_of_fit``, ``excluded_segments``, ``heldout`` where the finder
    had none (``null`` / empty, with a note)."""
    doc.setdefault("format", "encdesign-diagnosis/2")
    doc.setdefault("kind", rec.kind)
    doc.setdefault("recording", str(rec.path) if rec.path is not None else None)
    doc.setdefault("unit", "rad")
    for e in doc.get("effects", []):
        e.setdefault("delta_bic", None)
        e.setdefault("collinearity", None)
        e.setdefault("notes", [])
        e.setdefault("explanation", "")
        e["params"] = {
            k: v
            if isinstance(v, dict) and {"value", "se", "unit"} <= set(v)
            else {"value": v, "se": None, "unit": _unit_of(k)}
            for k, v in (e.get("params") or {}).items()
        }
    doc.setdefault("goodness_of_fit", None)
    doc.setdefault("excluded_segments", [])
    if not isinstance(doc.get("heldout"), dict):
        if doc.get("heldout") is not None:
            doc["heldout_scheme"] = str(doc["heldout"])
        doc["heldout"] = None
    doc.setdefault("unexplained", [])
    doc.setdefault("notes", [])
    doc["notes"] = list(doc["notes"]) + [
        f"the {rec.kind} finder is not yet routed through the common engine: no "
        "goodness-of-fit test, no non-steady segment detection"
    ]
    return doc
