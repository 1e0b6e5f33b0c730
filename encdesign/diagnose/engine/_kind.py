"""The kind protocol: :class:`AbstractKind`, what every recording kind gives the engine.

Equinox style: an abstract module with abstract ``data``, ``views``, ``base``, ``candidates``,
``max_order_limit`` and ``plots`` and defaulted hooks (``prepare``, ``noise``, ``refine``,
``align``, ``summary``, ``finish``, ``report_lines``); each kind (``kinds/multihead``:
multihead and one sensor against a reference; ``kinds/motion``; ``kinds/sds``;
``kinds/quadrature``) is a final subclass, registered in ``encdesign.diagnose._registry``.
"""

from __future__ import annotations

import abc
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import equinox as eqx
import numpy as np

from ._candidates import Candidate, Context
from ._prepare import prepare as engine_prepare
from ._protocol import KindData, Prepared
from ._settings import DEFAULT_SETTINGS, FinderSettings


class AbstractKind(eqx.Module):
    """A recording kind: how to read it, its base model, its views and its candidates.

    Class attributes (each final kind sets them):
        name: kind name.
        default_max_order: the base model's order when the user gives none.
        noise_replaces: ``True``: the kind's :meth:`noise` replaces the periodogram median
            (``sds``: levels by degrees of freedom, rows are platform positions, not time).
        grows_orders: ``True``: integer orders above ``default_max_order`` that the base
            residual shows (up to what the record resolves) join the base model (a disk's
            error function has every order).
        reading_lattice: ``True``: the channels are angle readings; one on a value lattice
            whose floor is a material part of its noise names ``quantization`` from the
            lattice.
    """

    name: ClassVar[str]
    default_max_order: ClassVar[int] = 12
    noise_replaces: ClassVar[bool] = False
    grows_orders: ClassVar[bool] = False
    reading_lattice: ClassVar[bool] = False

    @abc.abstractmethod
    def data(self, rec, settings: FinderSettings = DEFAULT_SETTINGS) -> KindData:
        """The observations and row columns of a recording (raises EncdesignInputError);
        ``settings``: the run's thresholds (e.g. the SDS time-stamp lattice)."""

    @abc.abstractmethod
    def views(self, prep: Prepared) -> tuple[str | Callable[..., Any], ...]:
        """The views run on this record's residual: names of the engine's views
        (:mod:`~encdesign.diagnose.engine._views`) or the kind's own view functions,
        ``view(prep, whitened_residual, scan_order) -> [Finding, ...]``."""

    @abc.abstractmethod
    def plots(self, d: Any, folder: str | os.PathLike) -> list[Path]:
        """The kind's own figures of a finished diagnosis ``d`` (a
        :class:`~encdesign.diagnose.Diagnosis`), written into ``folder`` beside the engine's
        (:func:`~encdesign.diagnose.engine._plots.engine_plots`); their paths."""

    @abc.abstractmethod
    def base(self, prep: Prepared, max_order: int) -> tuple[list, dict]:
        """``([(Candidate, start), ...], info)``: the base-model terms for this record
        (``info``: ``unidentifiable`` names, the ``refine`` / ``align`` callables the
        defaulted :meth:`refine` and :meth:`align` call, kind keys for the JSON)."""

    @abc.abstractmethod
    def candidates(self, ctx: Context) -> tuple[Candidate, ...]:
        """The kind's catalog of candidate effects for this record."""

    @abc.abstractmethod
    def max_order_limit(self, prep: Prepared) -> int:
        """The highest base order this record resolves."""

    def prepare(self, kd: KindData, meta: dict, settings: FinderSettings) -> Prepared:
        """Stage 1 (the engine's :func:`~encdesign.diagnose.engine._prepare.prepare`; replaced by a
        kind whose rows are not a time series of a turning shaft: ``sds``)."""
        return engine_prepare(kd, meta, settings)

    def noise(self, prep: Prepared, base_resid: np.ndarray) -> np.ndarray | None:
        """A second noise estimate ``(C,)`` the kind's own structure cannot inflate (the
        engine takes, per channel, the smaller of it and the periodogram median), or
        ``None``."""
        return None

    def refine(self, terms: list, prep: Prepared, info: dict) -> str | None:
        """After the base fit: move the angle the base is evaluated at (a note, or
        ``None`` when nothing moved; the engine then refits)."""
        hook = info.get("refine")
        return hook(terms, prep) if hook is not None else None

    def align(self, terms: list, prep: Prepared, info: dict):
        """After each base fit: the aligned angle rotation-locked candidates see (an array
        or a lazy column ``fn(lo, hi)``), or ``None``."""
        hook = info.get("align")
        return hook(terms, prep) if hook is not None else None

    def summary(self, prep: Prepared, base_params: dict) -> dict:
        """Kind-specific keys for the JSON document."""
        return {}

    def finish(self, prep: Prepared, doc: dict, settings: FinderSettings) -> dict:
        """The kind's additions to the engine's document (effects named from a lattice,
        located structure no term models, notes), before the engine decides the verdict and
        builds the report once."""
        return doc

    def report_lines(self, doc: dict) -> str:
        """The kind's lines appended to the plain-text report."""
        return ""
