"""Typed results of a diagnosis: :class:`Effect`, :class:`Finding`, :class:`Refusal`,
:class:`Alternative`, :class:`Confounded`, :class:`BaseOrder` (with its :class:`OrderTrial`)
and :class:`PlotData` (equinox Modules, final,
their invariants checked in ``__check_init__``).

Each entry is built from its JSON form (:meth:`from_json`) and gives it back unchanged
(:meth:`to_json`, the document of ``diagnosis.schema.json`` / ``docs/diagnose.md``): the keys
the schema documents are typed fields; keys a kind adds beyond them (a quadrature clipping
finding's ``fraction_of_samples``, ...) stay in ``extra``; ``key_order`` is the entry's key order
in the document (absent keys are absent, not ``None``). The :class:`Diagnosis` that holds
them lives in :mod:`encdesign.diagnose._dispatch`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar, final

import equinox as eqx
import numpy as np

from ..._errors import DiagnosisError

if TYPE_CHECKING:
    from ._protocol import Prepared

VERDICTS = ("consistent", "missing_physics", "unexplained")
"""The three verdicts of a diagnosis."""

WHERE_KEYS = ("orders", "frequencies_hz", "heads", "runs", "times_s")
"""The keys every ``where`` (a finding's location) carries."""


def _bad(what: str, got: object, expected: str) -> DiagnosisError:
    return DiagnosisError(f"diagnosis result {what}: got {got!r}; expected {expected}")


def _opt_number(v: object) -> bool:
    return v is None or (isinstance(v, int | float) and not isinstance(v, bool))


class _Entry(eqx.Module):
    """Common JSON round trip of the typed entries (abstract: each final entry declares
    ``extra`` and ``key_order``)."""

    if TYPE_CHECKING:  # declared by each final entry (fields after its own)
        extra: Mapping[str, object]
        key_order: tuple[str, ...]

    TYPED: ClassVar[tuple[str, ...]] = ()
    """The JSON keys that are typed fields, in the document's usual order."""
    NESTED: ClassVar[Mapping[str, type[_Entry]]] = {}
    """Typed fields that hold a tuple of entries (key -> entry class)."""
    TUPLES: ClassVar[tuple[str, ...]] = ()
    """Typed fields held as tuples (lists in the JSON)."""

    @classmethod
    def from_json(cls, d: Mapping[str, Any]):
        """The typed entry of a JSON entry ``d`` (its keys and their order kept)."""
        kw: dict[str, Any] = {}
        for k in cls.TYPED:
            if k not in d:
                continue
            v = d[k]
            if k in cls.NESTED and v is not None:
                v = tuple(cls.NESTED[k].from_json(x) for x in v)
            elif k in cls.TUPLES and v is not None:
                v = tuple(v)
            kw[k] = v
        extra = {k: v for k, v in d.items() if k not in cls.TYPED}
        return cls(**kw, extra=extra, key_order=tuple(d))

    def to_json(self) -> dict[str, Any]:
        """The JSON entry (the document's form, keys in the order they came)."""
        out: dict[str, Any] = {}
        for k in self.key_order:
            if k not in self.TYPED:
                out[k] = self.extra[k]
                continue
            v = getattr(self, k)
            if k in self.NESTED and v is not None:
                v = [x.to_json() for x in v]
            elif k in self.TUPLES and v is not None:
                v = list(v)
            out[k] = v
        return out

    def __getitem__(self, key: str) -> Any:
        """Back compatibility: ``entry["name"]`` reads the JSON entry's key."""
        return self.to_json()[key]


def _keys_ok(entry: _Entry, required: tuple[str, ...]) -> None:
    missing = [k for k in required if k not in entry.key_order]
    if missing:
        raise _bad(f"{type(entry).__name__} {getattr(entry, 'name', '')!r}", missing, "present")
    unknown = [k for k in entry.key_order if k not in entry.TYPED and k not in entry.extra]
    if unknown:
        raise _bad(type(entry).__name__, unknown, "keys with a value")


@final
class Alternative(_Entry):
    """An effect that fits nearly as well as a named one (an entry of ``confounded_with``
    or of ``alternatives``).

    Attributes:
        name: the candidate's name.
        reason: why it is an alternative, and what would tell the two apart.
        rule: the acceptance rule that put it here (``tie_chi2``, ``dominant_doubted``).
        delta_bic: its own change of the information criterion (``None``: not fitted).
        delta_bic_vs: its criterion less the named effect's (> 0: it fits worse).
        separate_by: what measurement would tell it from the named effect.
        correlation: the correlation of what it and the named effect take out of the
            residual (ties; in [0, 1]).
        params: its fitted parameters (``{name: value}``).
    """

    name: str
    reason: str = ""
    rule: str | None = None
    delta_bic: float | None = None
    delta_bic_vs: float | None = None
    separate_by: str | None = None
    correlation: float | None = None
    params: Mapping[str, Any] | None = None
    extra: Mapping[str, object] = dataclasses.field(default_factory=dict)
    key_order: tuple[str, ...] = ("name", "reason", "rule", "delta_bic", "params")

    TYPED: ClassVar[tuple[str, ...]] = (
        "name",
        "reason",
        "rule",
        "delta_bic",
        "delta_bic_vs",
        "separate_by",
        "correlation",
        "params",
    )

    def __check_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise _bad("Alternative.name", self.name, "a non-empty string")
        if not _opt_number(self.delta_bic) or not _opt_number(self.delta_bic_vs):
            raise _bad(f"Alternative {self.name!r} delta_bic", self.delta_bic, "a number")
        _keys_ok(self, ("name", "reason"))


_EFFECT_KEYS = (
    "name",
    "params",
    "derived",
    "channels",
    "rms_after",
    "heldout_rms_after",
    "delta_bic",
    "delta_heldout_chi2",
    "collinearity",
    "share",
    "size_rms",
    "notes",
    "explanation",
    "confounded_with",
)
"""The keys of a named effect's JSON entry, in order (``doubt`` and ``alternatives`` follow
only when the effect is doubted)."""


@final
class Effect(_Entry):
    """A named effect (an entry of ``effects``).

    Attributes:
        name: the catalog name.
        params: ``{name: {"value", "se", "unit"}}`` (unit of the parameter).
        rms_after, heldout_rms_after: residual RMS with it, fitted and held out (unit of
            the document).
        delta_bic: change of the information criterion (< 0: better; ``None``: named from
            a lattice, not fitted).
        collinearity: canonical correlation with the base model, in [0, 1] (``None``).
        notes: notes on the fit.
        explanation: what the effect is physically.
        derived, channels, delta_heldout_chi2, share, size_rms: as documented in
            ``docs/diagnose.md`` (absent where a kind does not give them).
        confounded_with: candidates the data cannot tell from it (:class:`Alternative`).
        doubt: the plausibility rule that doubts it (``<candidate>.plausible`` or a
            settings field) and why, when it is named as the dominant candidate although
            a rule doubts it; else absent.
        alternatives: what fits nearly as well when it is doubted (:class:`Alternative`).
    """

    name: str
    params: Mapping[str, Any]
    rms_after: float | None
    heldout_rms_after: float | None
    delta_bic: float | None
    collinearity: float | None
    notes: tuple[str, ...] = ()
    explanation: str = ""
    derived: Mapping[str, Any] | None = None
    channels: tuple[str, ...] | None = None
    delta_heldout_chi2: float | None = None
    share: float | None = None
    size_rms: float | None = None
    confounded_with: tuple[Alternative, ...] | None = None
    doubt: Mapping[str, Any] | None = None
    alternatives: tuple[Alternative, ...] | None = None
    extra: Mapping[str, object] = dataclasses.field(default_factory=dict)
    key_order: tuple[str, ...] = _EFFECT_KEYS

    TYPED: ClassVar[tuple[str, ...]] = (*_EFFECT_KEYS, "doubt", "alternatives")
    NESTED: ClassVar[Mapping[str, type[_Entry]]] = {
        "confounded_with": Alternative,
        "alternatives": Alternative,
    }
    TUPLES: ClassVar[tuple[str, ...]] = ("notes", "channels")

    def __check_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise _bad("Effect.name", self.name, "a non-empty string")
        c = self.collinearity
        if c is not None and not (0.0 <= c <= 1.0 + 1e-12):
            raise _bad(f"Effect {self.name!r} collinearity", c, "a number in [0, 1]")
        for k in ("rms_after", "heldout_rms_after"):
            v = getattr(self, k)
            if v is not None and not (v >= 0.0 or math.isnan(v)):
                raise _bad(f"Effect {self.name!r} {k}", v, "a number >= 0")
        if not _opt_number(self.delta_bic):
            raise _bad(f"Effect {self.name!r} delta_bic", self.delta_bic, "a number or None")
        if self.doubt is not None and not {"rule", "reason"} <= set(self.doubt):
            raise _bad(f"Effect {self.name!r} doubt", self.doubt, "{'rule', 'reason'}")
        _keys_ok(
            self,
            (
                "name",
                "params",
                "rms_after",
                "heldout_rms_after",
                "delta_bic",
                "collinearity",
                "notes",
                "explanation",
            ),
        )


@final
class Finding(_Entry):
    """Located structure no named effect explains (an entry of ``unexplained``).

    Attributes:
        view: the view that located it (``orders``, ``time``, ``spectrum``, ...; a kind's
            own: ``clipping``).
        where: where it sits (``orders``, ``frequencies_hz``, ``heads``, ``runs``,
            ``times_s``: lists).
        rms: its RMS (unit of the document; ``None`` where not finite).
        variance_share, log10_p, detail, note: as documented (absent where a kind does not
            give them).
        model: what discovery models of it outside the catalog (issue 41): ``frame``,
            ``terms`` (each with its frame, modulation, scaling, parameters, held-out gain,
            inclusion probability and reading), ``reading``; ``terms`` empty and a
            ``reason`` where nothing in the library holds; absent where discovery does not
            apply (an SDS record, a finding a kind adds).
    """

    where: Mapping[str, Any]
    rms: float | None
    view: str | None = None
    variance_share: float | None = None
    log10_p: float | None = None
    detail: Mapping[str, Any] | None = None
    note: str | None = None
    model: Mapping[str, Any] | None = None
    extra: Mapping[str, object] = dataclasses.field(default_factory=dict)
    TYPED: ClassVar[tuple[str, ...]] = (
        "view",
        "where",
        "rms",
        "variance_share",
        "log10_p",
        "detail",
        "note",
        "model",
    )
    key_order: tuple[str, ...] = TYPED[:-1]

    def __check_init__(self):
        missing = [k for k in WHERE_KEYS if k not in self.where]
        if missing:
            raise _bad(f"Finding ({self.view}) where", missing, f"the keys {WHERE_KEYS}")
        if self.rms is not None and self.rms < 0:
            raise _bad(f"Finding ({self.view}) rms", self.rms, "a number >= 0")
        m = self.model
        if m is not None and not (m.get("outside_catalog") is True and "terms" in m):
            raise _bad(f"Finding ({self.view}) model", m, "{'outside_catalog': True, 'terms'}")
        _keys_ok(self, ("where", "rms"))

    @property
    def times_s(self) -> tuple[float, ...]:
        """Located times within the run (s)."""
        return tuple(self.where["times_s"])

    @property
    def orders(self) -> tuple[float, ...]:
        """Located orders (cycles per turn)."""
        return tuple(self.where["orders"])


@final
class Refusal(_Entry):
    """A refused candidate (an entry of ``rejected``) or one that does not apply (of
    ``not_testable``).

    Attributes:
        name: the candidate's name.
        reason: why, in words.
        rule: the first acceptance rule that refused it (a ``FinderSettings`` field or a
            named rule: ``identifiable``, ``better_candidate``, ``<candidate>.plausible``,
            ``applies``, ...).
        rules: every rule that refused it.
        delta_bic: its change of the information criterion, where it was fitted.
    """

    name: str
    reason: str
    rule: str | None = None
    rules: tuple[str, ...] | None = None
    delta_bic: float | None = None
    extra: Mapping[str, object] = dataclasses.field(default_factory=dict)
    TYPED: ClassVar[tuple[str, ...]] = ("name", "reason", "rule", "rules", "delta_bic")
    key_order: tuple[str, ...] = TYPED
    TUPLES: ClassVar[tuple[str, ...]] = ("rules",)

    def __check_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise _bad("Refusal.name", self.name, "a non-empty string")
        if not isinstance(self.reason, str):
            raise _bad(f"Refusal {self.name!r} reason", self.reason, "a string")
        if self.rules is not None and self.rule is not None and self.rule not in self.rules:
            raise _bad(f"Refusal {self.name!r} rule", self.rule, f"one of {self.rules}")
        _keys_ok(self, ("name", "reason"))


@final
class DetectionBound(_Entry):
    """The smallest size of one catalog effect this record would have revealed (an entry
    of ``detection_bounds``, of a catalog effect the record did not name, against the final
    model; issue 44 F, :mod:`encdesign.diagnose.engine._bounds`).

    Attributes:
        effect: the candidate's name.
        parameter: the size's name (``delay_step_s``, ``amplitude_rad``).
        unit: its SI unit.
        where: the head or sensor it acts on, or ``"all"``.
        at: where its other parameters are held, in words.
        bound: the size detected with about 50 % probability (``unit``), or ``None`` (with a
            ``note`` in ``extra``) when no size would be revealed.
        set_by: the test that sets it (``view``, ``bic_min``, ``heldout_min``, and where
            structure is left unexplained ``located_share_min``, ``signature_left_max``).
        noncentrality: the effect's noncentrality at the bound.
        n_params: the candidate's fitted parameters ``k``.
        convention: what the bound means.
    """

    effect: str
    parameter: str
    unit: str
    where: str
    at: str
    bound: float | None
    set_by: str | None
    noncentrality: float | None
    n_params: int | None
    convention: str
    extra: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    TYPED: ClassVar[tuple[str, ...]] = (
        "effect",
        "parameter",
        "unit",
        "where",
        "at",
        "bound",
        "set_by",
        "noncentrality",
        "n_params",
        "convention",
    )
    key_order: tuple[str, ...] = TYPED

    def __check_init__(self):
        if not isinstance(self.effect, str) or not self.effect:
            raise _bad("DetectionBound.effect", self.effect, "a non-empty string")
        if self.bound is not None and not (_opt_number(self.bound) and self.bound > 0):
            raise _bad(f"DetectionBound {self.effect!r} bound", self.bound, "a number > 0")
        if self.bound is None and "note" not in self.extra:
            raise _bad(f"DetectionBound {self.effect!r}", self.extra, "a note without a bound")
        _keys_ok(self, self.TYPED)


@final
class Confounded(_Entry):
    """Two effects the record cannot separate (an entry of ``confounded``): reported as
    one entry, never as two refusals.

    Attributes:
        pair: the two candidates' names (the first one is named in ``effects``).
        correlation: the correlation of what each takes out of the residual (kept rows,
            noise-whitened), in [0, 1].
        delta_bic: the second's criterion less the first's (>= 0).
        separate_by: what measurement would separate them.
        reason: why they are confounded, in words.
    """

    pair: tuple[str, str]
    correlation: float
    delta_bic: float | None
    separate_by: str
    reason: str = ""
    extra: Mapping[str, object] = dataclasses.field(default_factory=dict)
    TYPED: ClassVar[tuple[str, ...]] = ("pair", "correlation", "delta_bic", "separate_by", "reason")
    key_order: tuple[str, ...] = TYPED
    TUPLES: ClassVar[tuple[str, ...]] = ("pair",)

    def __check_init__(self):
        if len(self.pair) != 2 or self.pair[0] == self.pair[1]:
            raise _bad("Confounded.pair", self.pair, "two different names")
        if not (0.0 <= self.correlation <= 1.0 + 1e-12):
            raise _bad(f"Confounded {self.pair} correlation", self.correlation, "in [0, 1]")
        _keys_ok(self, ("pair", "correlation", "delta_bic", "separate_by"))


@final
class OrderTrial(_Entry):
    """One base order tried by the held-out choice (an entry of ``base_order.tried``).

    Attributes:
        order: the base model's highest order ``M`` (orders 1..M).
        rms: the base's fitted residual RMS at that order (unit of the document).
        heldout_rms: its K-fold held-out residual RMS, in the engine's folds.
        heldout_chi2: its K-fold held-out chi-square (noise-whitened; the choice's measure).
        n_params: its fitted (determined) parameters.
    """

    order: int
    rms: float
    heldout_rms: float
    heldout_chi2: float | None = None
    n_params: int | None = None
    extra: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    TYPED: ClassVar[tuple[str, ...]] = ("order", "rms", "heldout_rms", "heldout_chi2", "n_params")
    key_order: tuple[str, ...] = TYPED

    def __check_init__(self):
        if isinstance(self.order, bool) or not isinstance(self.order, int) or self.order < 1:
            raise _bad("OrderTrial.order", self.order, "an integer >= 1")
        for k in ("rms", "heldout_rms"):
            v = getattr(self, k)
            if not isinstance(v, int | float) or not (v >= 0.0 or math.isnan(v)):
                raise _bad(f"OrderTrial {self.order} {k}", v, "a number >= 0")
        _keys_ok(self, ("order", "rms", "heldout_rms"))


@final
class BaseOrder(_Entry):
    """How the base model's order was chosen (the document's ``base_order``; issue 44 E).

    Attributes:
        start: the default order (the kind's default, within what the record resolves).
        chosen: the order the base model was fitted at before any growth (``base.max_order``
            holds the final one, after growth).
        lowered: whether held-out error lowered it below ``start``.
        heldout_ratio: the base's held-out RMS over its fitted RMS at ``start``.
        ratio_max: ``FinderSettings.base_order_ratio``: above it the orders ``1..start`` are
            tried.
        tried: each tried order's fitted and held-out RMS (:class:`OrderTrial`); only
            ``start`` when the ratio is within ``ratio_max``.
        reason: the choice, in words.
        extra: ``again`` (session 36): where effects were named on a lowered order, the
            same choice made again beside them (their names, each tried order, the order).
    """

    start: int
    chosen: int
    lowered: bool
    heldout_ratio: float
    ratio_max: float
    tried: tuple[OrderTrial, ...]
    reason: str = ""
    extra: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    TYPED: ClassVar[tuple[str, ...]] = (
        "start",
        "chosen",
        "lowered",
        "heldout_ratio",
        "ratio_max",
        "tried",
        "reason",
    )
    key_order: tuple[str, ...] = TYPED
    NESTED: ClassVar[Mapping[str, Any]] = {"tried": OrderTrial}

    def __check_init__(self):
        if not (1 <= self.chosen <= self.start):
            raise _bad("BaseOrder.chosen", self.chosen, f"an order in 1..{self.start}")
        if self.lowered != (self.chosen < self.start):
            raise _bad("BaseOrder.lowered", self.lowered, "chosen < start")
        if self.chosen not in {t.order for t in self.tried}:
            raise _bad("BaseOrder.tried", [t.order for t in self.tried], "the chosen order")
        _keys_ok(self, self.TYPED)

    @property
    def trial(self) -> OrderTrial:
        """The chosen order's trial."""
        return next(t for t in self.tried if t.order == self.chosen)


@final
class PlotData(eqx.Module):
    """What the figures need beyond the document (not part of the JSON).

    Attributes:
        prep: the engine's prepared recording (rows, kept mask, runs, channels).
        base_resid: (n, C) residual of the base model (unit of the document).
        final_resid: (n, C) residual of the final model.
        effect_contributions: ``{effect name: (n, C) its own fitted contribution}`` (the
            named effects of the final model, evaluated alone; projected like the residual).
    """

    prep: Prepared
    base_resid: np.ndarray
    final_resid: np.ndarray
    effect_contributions: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def __getitem__(self, key: str) -> Any:
        """Back compatibility: ``plot_data["prep"]``."""
        return getattr(self, key)
