"""Fits that travel between processes (issue 43, :mod:`._workshare`): a selection round's
trial fits are dealt over the processes, each on a fitter of its own, and gathered."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence
from typing import cast

from ._candidates import Candidate
from ._fit import FitResult, Fitter
from ._normal import BlockCache


def private(fitter: Fitter) -> Fitter:
    """A fitter of its own for a share of work items: ``fitter``'s state with its caches
    copied (every dict, list and set it holds, and those of its
    :class:`~._normal.BlockCache`), so that what the work caches stays there."""
    out = copy.copy(fitter)
    for k, v in vars(fitter).items():
        if isinstance(v, BlockCache):
            v = _copied(copy.copy(v))
        setattr(out, k, copy.copy(v) if isinstance(v, dict | list | set) else v)
    return out


def _copied(obj):
    """``obj`` with each dict, list and set attribute replaced by a shallow copy."""
    for k, v in vars(obj).items():
        if isinstance(v, dict | list | set):
            setattr(obj, k, copy.copy(v))
    return obj


@dataclasses.dataclass(frozen=True)
class PackedFit:
    """A :class:`FitResult` without its candidates (which hold functions): its terms'
    candidates by name, in order."""

    names: tuple[str, ...]
    fit: FitResult


def pack_fit(fr: FitResult | None) -> PackedFit | None:
    """``fr`` ready to pickle (:func:`unpack_fit` restores it)."""
    if fr is None:
        return None
    terms = [dataclasses.replace(t, cand=cast(Candidate, None)) for t in fr.terms]
    return PackedFit(tuple(t.cand.name for t in fr.terms), dataclasses.replace(fr, terms=terms))


def unpack_fit(packed: PackedFit | None, cands: Sequence[Candidate]) -> FitResult | None:
    """The fit of ``packed`` with its terms' candidates ``cands`` (this process's objects,
    in the terms' order; the names must match)."""
    if packed is None:
        return None
    if tuple(c.name for c in cands) != packed.names:
        raise ValueError(f"unpack_fit: terms {packed.names} against {[c.name for c in cands]}")
    fr = copy.copy(packed.fit)
    fr.terms = [dataclasses.replace(t, cand=c) for t, c in zip(fr.terms, cands)]
    return fr


__all__ = ["PackedFit", "pack_fit", "private", "unpack_fit"]
