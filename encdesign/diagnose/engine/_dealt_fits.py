"""Fits that travel between processes (issue 43, :mod:`._workshare`): a selection round's
trial fits are made on their candidates' home processes (:mod:`._homes`), each process's on
a fitter of its own, and gathered."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import cast

from ._candidates import Candidate
from ._fit import FitResult, Fitter
from ._normal import BlockCache
from ._workshare import deal


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


def dealt_trials(
    cands: Sequence[Candidate],
    model: Sequence[Candidate],
    home: Mapping[str, int],
    run: Callable[[list[Candidate]], list[tuple]],
) -> list[tuple]:
    """``run(cands)``'s results, ``(fit or None, *more)`` per candidate (``more``
    picklable), each candidate's made on its ``home`` process (``run`` of that process's
    candidates, in order, alone: :func:`._workshare.deal`) and gathered; each fit's terms
    are ``model``'s candidates and then its own."""

    def work(mine: list[int]) -> list[tuple]:
        return [(pack_fit(f), *more) for f, *more in run([cands[i] for i in mine])]

    got = deal(list(range(len(cands))), work, home=lambda i: home.get(cands[i].name, 0))
    return [(unpack_fit(pk, [*model, c]), *more) for c, (pk, *more) in zip(cands, got)]


__all__ = ["PackedFit", "dealt_trials", "pack_fit", "private", "unpack_fit"]
