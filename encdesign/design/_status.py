"""Driver statuses: one enumeration, a message each, and the one meaning of ``.ok``."""

from __future__ import annotations

import enum
from typing import Protocol, TypeVar

from .._errors import OptimisationError


class DriverStatus(enum.StrEnum):
    """How a driver finished (a ``str``: ``status == "success"`` and JSON keep working).

    :attr:`ok` is the one meaning of ``.ok`` on every result: the value is an answer
    (``SUCCESS``, or ``AT_BOUND``: converged with a variable on its bound, marked).
    """

    SUCCESS = "success"
    AT_BOUND = "at_bound"
    MAX_STEPS = "max_steps_reached"
    STALLED = "line_search_stalled"
    NONFINITE = "nonfinite"
    BOUNDS_VIOLATED = "bounds_violated"
    INFEASIBLE = "infeasible"
    NO_FAILURE_FOUND = "no_failure_found"
    FAILED = "failed"

    @property
    def ok(self) -> bool:
        """True when the status is an answer (``success`` or ``at_bound``)."""
        return self in (DriverStatus.SUCCESS, DriverStatus.AT_BOUND)

    @property
    def message(self) -> str:
        """What the status means, in one line."""
        return _STATUS_MESSAGES[self]


_STATUS_MESSAGES = {
    DriverStatus.SUCCESS: "converged",
    DriverStatus.AT_BOUND: "converged with a variable on its bound (an answer, marked)",
    DriverStatus.MAX_STEPS: "the step cap was reached before convergence",
    DriverStatus.STALLED: "the line search made no progress (no decrease, or a step size "
    "that collapsed, or a stop whose quasi-Newton step still predicts a decrease)",
    DriverStatus.NONFINITE: "a non-finite value or objective",
    DriverStatus.BOUNDS_VIOLATED: "the solution lies outside the bounds",
    DriverStatus.INFEASIBLE: "a constraint is violated at the solution",
    DriverStatus.NO_FAILURE_FOUND: "no start reached the failure region",
    DriverStatus.FAILED: "the driver failed",
}

SUCCESS = DriverStatus.SUCCESS
AT_BOUND = DriverStatus.AT_BOUND
MAX_STEPS = DriverStatus.MAX_STEPS
STALLED = DriverStatus.STALLED
NONFINITE = DriverStatus.NONFINITE
BOUNDS_VIOLATED = DriverStatus.BOUNDS_VIOLATED
INFEASIBLE = DriverStatus.INFEASIBLE
FAILED = DriverStatus.FAILED
STATUSES = tuple(DriverStatus)
ANSWERS = tuple(s for s in DriverStatus if s.ok)
"""Statuses whose value is a converged answer (an at-bound optimum is one, marked)."""


class _Result(Protocol):
    @property
    def status(self) -> DriverStatus: ...

    @property
    def message(self) -> str: ...


_R = TypeVar("_R", bound=_Result)


def finish(result: _R, throw: bool) -> _R:
    """``result``, or :class:`OptimisationError` when ``throw`` and it is not ok."""
    if throw and not result.status.ok:
        raise OptimisationError(f"{type(result).__name__}: {result.status}: {result.message}")
    return result
