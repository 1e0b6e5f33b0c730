"""One entry for the discrepancy finder over every recording kind: :func:`diagnose`.

Every recording goes through the one engine entry
(:func:`~encdesign.diagnose.engine._engine.run_engine`) with the kind object
:data:`~encdesign.diagnose._registry.KINDS` holds for its ``kind`` (``multihead``, including
one sensor against a reference, ``motion``, ``sds``, ``quadrature``: one folder each under
``kinds/``); every diagnosis follows one contract (``diagnosis.schema.json``).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, final

import equinox as eqx

from .._errors import DiagnosisError, input_error
from .._usercode import user_module_items
from ..io._recording import Recording, load_recording
from ._registry import KINDS
from .engine._candidates import Candidate
from .engine._engine import run_engine
from .engine._plots import engine_plots
from .engine._reduce_stream import stream_reduce
from .engine._results import (
    VERDICTS,
    BaseOrder,
    Confounded,
    DetectionBound,
    Effect,
    Finding,
    PlotData,
    Refusal,
)
from .engine._settings import DEFAULT_SETTINGS, FinderSettings

TYPED_KEYS = (
    "verdict",
    "status",
    "effects",
    "unexplained",
    "rejected",
    "not_testable",
    "confounded",
    "detection_bounds",
)
"""Keys of the document held as typed fields of :class:`Diagnosis`."""
_OPTIONAL_TYPED = ("confounded", "base_order")
"""Typed keys a document may lack (``base_order``: only where the engine chose an order)."""


@final
class Diagnosis(eqx.Module):
    """A diagnosis: typed results, the rest of the JSON document, and what the plots need.

    Attributes:
        verdict: ``consistent``, ``missing_physics`` or ``unexplained``.
        status: ``"ok"`` or why a fit did not converge.
        effects: named effects, most important first (:class:`Effect`).
        unexplained: located structure no effect explains (:class:`Finding`).
        rejected: refused candidates, each with its rule (:class:`Refusal`).
        not_testable: candidates that do not apply to this record (:class:`Refusal`).
        confounded: pairs of effects the record cannot separate (:class:`Confounded`;
            empty when the document has none).
        base_order: how the base model's order was chosen, each tried order's fitted and
            held-out RMS (:class:`BaseOrder`; ``None`` where the kind's order is fixed or
            the caller gave ``max_order``).
        detection_bounds: the smallest size of each catalog effect not named (per head or
            sensor) this record would have revealed, against the final model (the base and
            the named effects: ``other["detection_bounds_reference"]``)
            (:class:`DetectionBound`).
        other: every other key of the document (``docs/diagnose.md``), as JSON.
        key_order: the document's keys in order (:meth:`to_json` gives them back so).
        plot_data: what the figures need beyond the document (:class:`PlotData`).
    """

    verdict: str
    status: str
    effects: tuple[Effect, ...]
    unexplained: tuple[Finding, ...]
    rejected: tuple[Refusal, ...]
    not_testable: tuple[Refusal, ...]
    confounded: tuple[Confounded, ...]
    other: Mapping[str, Any]
    key_order: tuple[str, ...]
    plot_data: PlotData | None = None
    base_order: BaseOrder | None = None
    detection_bounds: tuple[DetectionBound, ...] = ()

    def __check_init__(self):
        if self.verdict not in VERDICTS:
            raise DiagnosisError(f"diagnosis verdict: got {self.verdict!r}; expected {VERDICTS}")
        if (self.verdict == "missing_physics") != bool(self.effects):
            raise DiagnosisError(
                f"diagnosis verdict {self.verdict!r} with {len(self.effects)} named effect(s): "
                "missing_physics exactly when an effect is named"
            )
        if self.verdict == "consistent" and self.unexplained:
            raise DiagnosisError("diagnosis verdict 'consistent' with unexplained structure")
        named = {e.name for e in self.effects}
        if any(b.effect in named for b in self.detection_bounds):
            raise DiagnosisError(
                "diagnosis with a detection bound of a named effect: the bounds are of the "
                "catalog effects the record did not name"
            )

    @classmethod
    def from_json(cls, doc: Mapping[str, Any], plot_data: PlotData | None = None) -> Diagnosis:
        """The typed diagnosis of a diagnosis document (``diagnosis.schema.json``)."""
        return cls(
            verdict=doc["verdict"],
            status=doc.get("status", "ok"),
            effects=tuple(Effect.from_json(e) for e in doc.get("effects", ())),
            unexplained=tuple(Finding.from_json(f) for f in doc.get("unexplained", ())),
            rejected=tuple(Refusal.from_json(r) for r in doc.get("rejected", ())),
            not_testable=tuple(Refusal.from_json(r) for r in doc.get("not_testable", ())),
            confounded=tuple(Confounded.from_json(c) for c in doc.get("confounded", ())),
            other={k: v for k, v in doc.items() if k not in (*TYPED_KEYS, *_OPTIONAL_TYPED)},
            key_order=tuple(doc),
            plot_data=plot_data,
            base_order=None
            if doc.get("base_order") is None
            else BaseOrder.from_json(doc["base_order"]),
            detection_bounds=tuple(
                DetectionBound.from_json(b) for b in doc.get("detection_bounds", ())
            ),
        )

    def to_json(self) -> dict[str, Any]:
        """The JSON document (``diagnosis.schema.json``, ``docs/diagnose.md``)."""
        typed: dict[str, Any] = {
            "verdict": self.verdict,
            "status": self.status,
            "effects": [e.to_json() for e in self.effects],
            "unexplained": [f.to_json() for f in self.unexplained],
            "rejected": [r.to_json() for r in self.rejected],
            "not_testable": [r.to_json() for r in self.not_testable],
            "confounded": [c.to_json() for c in self.confounded],
            "base_order": None if self.base_order is None else self.base_order.to_json(),
            "detection_bounds": [b.to_json() for b in self.detection_bounds],
        }
        return {k: typed[k] if k in typed else self.other[k] for k in self.key_order}

    @property
    def doc(self) -> dict[str, Any]:
        """The JSON document (back compatibility: :meth:`to_json`)."""
        return self.to_json()

    def _repr_html_(self) -> str:
        """Jupyter's rich display: the HTML report's verdict line and tables (no figures;
        :func:`~encdesign.diagnose.render_diagnosis_html` gives the whole report)."""
        from .engine._html import notebook_html

        return notebook_html(self)

    def __getitem__(self, key: str) -> Any:
        """Back compatibility: ``d["verdict"]`` reads the document's key."""
        return self.to_json()[key]

    def with_keys(self, **keys: object) -> Diagnosis:
        """A copy with document keys other than the typed ones set (e.g. ``plots``)."""
        if set(keys) & {*TYPED_KEYS, *_OPTIONAL_TYPED}:
            raise DiagnosisError(f"with_keys: typed keys {sorted(keys)} are set as fields")
        order = self.key_order + tuple(k for k in keys if k not in self.key_order)
        return dataclasses.replace(self, other={**self.other, **keys}, key_order=order)


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
        ("fn", "applies", "start", "plausible", "derived", "probes"),
    )


def open_recording(
    path: str | os.PathLike,
    *,
    max_order: int | None = None,
    settings: FinderSettings | None = None,
) -> tuple[Recording, dict | None]:
    """The recording of the TOML file ``path`` and its ``reduced`` entry: a long Parquet
    record is reduced to block means as it is read, row group by row group (issue 43,
    ``FinderSettings.reduce_min_rows``; the whole table is never in memory); any other is
    loaded whole (``None``). In a program that joined ``jax.distributed`` (``--processes``,
    ``--coordinator``) every process must call it: each reads and reduces its share of the
    row groups, and every process gets the same reduced record.

    Raises:
        EncdesignInputError: the file breaks the format (the message names the file, the
            row group and the column).
    """
    s = DEFAULT_SETTINGS if settings is None else settings

    def order_of(name: str) -> tuple[int, bool]:
        k = KINDS[name]
        own = max_order is None
        return (k.default_max_order if own else int(max_order)), k.grows_orders and own

    got = stream_reduce(path, s, order_of)
    return got if got is not None else (load_recording(path), None)


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
    reduced: dict | None = None,
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
        reduced: with a ``recording`` that :func:`open_recording` reduced, its entry (the
            record is not reduced again).

    Raises:
        EncdesignInputError: a recording that cannot be diagnosed.
    """
    if not isinstance(recording, Recording):
        recording, reduced = open_recording(recording, max_order=max_order, settings=settings)
    rec = recording
    kind = KINDS.get(rec.kind)
    if kind is None:
        raise input_error(
            "kind", f"no finder for recording kind {rec.kind!r}", f"one of {tuple(KINDS)}"
        )
    doc, plot_data = run_engine(
        kind,
        rec,
        max_order=max_order,
        max_effects=max_effects,
        extra_candidates=candidates,
        verbose=verbose,
        settings=settings,
        reduced=reduced,
    )
    d = Diagnosis.from_json(doc, plot_data)
    if plots is not None:
        paths = [*engine_plots(d, plots), *kind.plots(d, plots)]
        d = d.with_keys(plots=[str(p) for p in paths])
    if throw and d.status != "ok":
        raise DiagnosisError(f"diagnose: {d.status}")
    return d
