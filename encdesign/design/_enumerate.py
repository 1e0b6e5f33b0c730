"""Enumeration of discrete variables wrapped around a continuous solve (no settings, so no
driver object: :func:`enumerate_designs` is the driver)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from .._progress import progress_bar
from ._status import ANSWERS, FAILED, SUCCESS, DriverStatus, finish


@dataclasses.dataclass(frozen=True)
class EnumerationResult:
    """Result of :func:`enumerate_designs`.

    Attributes:
        choices: the discrete combinations tried, as dicts, in order.
        solutions: the inner result for each combination (anything with ``status`` and
            ``objective``).
        best_index: index of the best combination whose status is an answer
            (:data:`ANSWERS`: ``"success"`` or ``"at_bound"``; ``-1`` if none).
        status: ``"success"`` when at least one combination succeeded and the best is a
            plain success; the best one's status (``"at_bound"``) when it is marked; else
            ``"failed"``.
        message: account of the status.
    """

    choices: tuple[dict[str, Any], ...]
    solutions: tuple[Any, ...]
    best_index: int
    status: DriverStatus
    message: str = ""

    @property
    def ok(self) -> bool:
        """True when the best combination is an answer (``success`` or ``at_bound``)."""
        return self.status.ok

    @property
    def best_choice(self) -> dict[str, Any]:
        """The best discrete combination."""
        return self.choices[self.best_index]

    @property
    def best_solution(self) -> Any:
        """The inner solution at the best combination."""
        return self.solutions[self.best_index]

    def _repr_html_(self) -> str:
        """Jupyter's rich display: the status and the key numbers."""
        from ._display import enumeration_html

        return enumeration_html(self)


def enumerate_designs(
    solve: Callable[[dict[str, Any]], Any],
    choices: Mapping[str, Sequence[Any]],
    *,
    progress: bool = False,
    throw: bool = False,
) -> EnumerationResult:
    """Solve the continuous problem for every combination of discrete values.

    Args:
        solve: ``solve(combination) -> result`` with ``.status`` and ``.objective`` (e.g. a
            closure calling :func:`optimise` for fixed discrete values).
        choices: variable name -> allowed values; the full product is enumerated.
        progress: show a progress line.
        throw: raise unless some combination succeeded.

    Returns:
        An :class:`EnumerationResult`; the best combination is the successful one with
        the smallest ``objective``. Failed combinations stay in the table with their status.
    """
    names = list(choices)
    combos = [dict(zip(names, vals)) for vals in itertools.product(*choices.values())]
    sols = []
    with progress_bar("enumerate", len(combos), enabled=progress) as bar:
        for c in combos:
            sols.append(solve(c))
            bar.update()
    okidx = [i for i, s in enumerate(sols) if s.status in ANSWERS and math.isfinite(s.objective)]
    if okidx:
        best = min(okidx, key=lambda i: sols[i].objective)
        status, msg = SUCCESS, f"{len(okidx)}/{len(combos)} combinations solved"
        if sols[best].status != SUCCESS:  # the best answer is marked (e.g. on a bound)
            status = sols[best].status
            msg = f"{msg}; the best is {status}: {getattr(sols[best], 'message', '')}"
    else:
        best, status, msg = -1, FAILED, "no combination solved"
    return finish(EnumerationResult(tuple(combos), tuple(sols), best, status, msg), throw)
