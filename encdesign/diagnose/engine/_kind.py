"""The kind protocol: :class:`AbstractKind`, what every recording kind gives the engine.

Equinox style: an abstract module whose class attributes (``eqx.AbstractClassVar``) and hooks
(``data``, ``views``, ``prepare``, ``base``, ``candidates``, ``max_order_limit``, ``noise``,
``refine``, ``align``, ``summary``, ``finish``, ``report_lines``, ``plots``) are all
abstract: each kind (``kinds/multihead``: multihead and one sensor against a reference;
``kinds/motion``; ``kinds/sds``; ``kinds/quadrature``) is a final subclass that gives every
one of them, so a reader sees a kind's whole behaviour in its own class. A kind that needs
no hook of its own calls the engine's (:func:`~encdesign.diagnose.engine._prepare.prepare`)
or returns the neutral value the hook's docstring names. Kinds are registered in
``encdesign.diagnose._registry``.
"""

from __future__ import annotations

import abc
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import equinox as eqx
import numpy as np

from ._candidates import Candidate, Context
from ._protocol import KindData, NoiseEstimate, Prepared
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

    name: eqx.AbstractClassVar[str]
    default_max_order: eqx.AbstractClassVar[int]
    noise_replaces: eqx.AbstractClassVar[bool]
    grows_orders: eqx.AbstractClassVar[bool]
    reading_lattice: eqx.AbstractClassVar[bool]

    @abc.abstractmethod
    def data(self, rec, settings: FinderSettings = DEFAULT_SETTINGS) -> KindData:
        """The observations and row columns of a recording (raises EncdesignInputError), in a
        :class:`KindData` or the kind's own subclass of it (the typed state its hooks read,
        built here once); ``settings``: the run's thresholds (e.g. the SDS time-stamp
        lattice)."""

    @abc.abstractmethod
    def views(self, prep: Prepared) -> tuple[str | Callable[..., Any], ...]:
        """The views run on this record's residual: names of the engine's views
        (:mod:`~encdesign.diagnose.engine._views`) or the kind's own view functions,
        ``view(prep, whitened_residual, scan_order) -> [Finding, ...]``."""

    @abc.abstractmethod
    def prepare(self, kd: KindData, meta: dict, settings: FinderSettings) -> Prepared:
        """Stage 1: the engine's :func:`~encdesign.diagnose.engine._prepare.prepare` for a
        time series of a turning shaft; a kind whose rows are not one (``sds``) has its
        own."""

    @abc.abstractmethod
    def base(self, prep: Prepared, max_order: int) -> tuple[list, dict]:
        """``([(Candidate, start), ...], info)``: the base-model terms for this record
        (``info``: ``unidentifiable`` names and the kind's keys for the JSON ``base``)."""

    @abc.abstractmethod
    def candidates(self, ctx: Context) -> tuple[Candidate, ...]:
        """The kind's catalog of candidate effects for this record."""

    @abc.abstractmethod
    def max_order_limit(self, prep: Prepared) -> int:
        """The highest base order this record resolves."""

    def growth_order_limit(self, prep: Prepared) -> int:
        """The highest order the base's growth (``grows_orders``) may reach, past the
        parameter budget of :meth:`max_order_limit` (``settings.growth_param_fraction``);
        the default: :meth:`max_order_limit`."""
        return self.max_order_limit(prep)

    @abc.abstractmethod
    def noise(self, prep: Prepared, base_resid: np.ndarray) -> NoiseEstimate | None:
        """A second noise estimate the kind's own structure cannot inflate (the engine
        takes, per channel, the smaller of its ``sigma`` and the periodogram median; with
        ``noise_replaces`` it replaces it; its ``info`` goes to the candidates as
        ``Context.noise_info``), or ``None``."""

    @abc.abstractmethod
    def refine(self, terms: list, prep: Prepared) -> str | None:
        """After the base fit: move the angle the base is evaluated at (a note, or
        ``None`` when nothing moved; the engine then refits)."""

    def check_base(self, terms: list, prep: Prepared) -> str | None:
        """After each base fit: hold a nuisance the fit moved where the kind's own evidence
        rejects it (values and free masks of ``terms`` changed in place: a note, the engine
        then refits), or ``None`` (nothing held; the default)."""
        return None

    @abc.abstractmethod
    def align(self, terms: list, prep: Prepared) -> np.ndarray | Callable[..., Any] | None:
        """After each base fit: the aligned angle rotation-locked candidates see (an array
        or a lazy column ``fn(lo, hi)``), or ``None``."""

    @abc.abstractmethod
    def summary(self, prep: Prepared, base_params: dict) -> dict:
        """Kind-specific keys for the JSON document (``{}``: none)."""

    @abc.abstractmethod
    def finish(self, prep: Prepared, doc: dict, settings: FinderSettings) -> dict:
        """The kind's additions to the engine's document (effects named from a lattice,
        located structure no term models, notes), before the engine decides the verdict and
        builds the report once (``doc`` itself: none)."""

    @abc.abstractmethod
    def report_lines(self, doc: dict) -> str:
        """The kind's lines appended to the plain-text report (``""``: none)."""

    @abc.abstractmethod
    def plots(self, d: Any, folder: str | os.PathLike) -> list[Path]:
        """The kind's own figures of a finished diagnosis ``d`` (a
        :class:`~encdesign.diagnose.Diagnosis`), written into ``folder`` beside the engine's
        (:func:`~encdesign.diagnose.engine._plots.engine_plots`); their paths (``[]``:
        none)."""
