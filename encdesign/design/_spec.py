"""What an objective declares to problem files: its variables and its registry entry.

Kept apart from :mod:`encdesign.design._problem` (which parses problem files) and
:mod:`encdesign.design._objectives` (which implements the built-in objectives) so that
both can import it and neither imports the other in a circle.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any

SI_UNITS = ("rad", "m", "s", "1")
"""The SI units a variable is declared in (problem files may use any unit of the same
dimension, :data:`encdesign.design._problem.UNITS`)."""


@dataclasses.dataclass(frozen=True)
class VariableInfo:
    """What an objective accepts for one design variable.

    Attributes:
        units: SI unit of the variable (``"rad"``, ``"m"``, ``"s"`` or ``"1"``).
        discrete: the variable only takes enumerated values (then it is never
            differentiated).
        integer: values must be integers (pole pairs, head counts).
        lower, upper: physical limits in SI (a problem's bounds must lie inside).
        doc: one line of description.
        values: the allowed values of a discrete variable (``None``: any); a problem lists
            a subset.
        start: default start (SI) when a problem's table gives none (a sequence for a
            vector variable).
        size: ``None`` for a scalar; for a vector variable (e.g. ``head_angles``) its
            length, ``0`` for any length ``>= 1``. A vector reaches the objective as one
            1-D array; drivers and case files see its elements ``name[i]``.
        check: ``check(start_si, where)`` raising
            :class:`~encdesign.EncdesignInputError` on an invalid start (e.g. coincident
            head azimuths); ``start_si`` is a float or, for a vector, a 1-D array.
    """

    units: str
    discrete: bool = False
    integer: bool = False
    lower: float = -math.inf
    upper: float = math.inf
    doc: str = ""
    values: tuple[Any, ...] | None = None
    start: Any = None
    size: int | None = None
    check: Callable[[Any, str], None] | None = dataclasses.field(default=None, compare=False)


@dataclasses.dataclass(frozen=True)
class ProblemObjective:
    """An objective that problem files can name (an entry of a registry).

    Attributes:
        name: the registry key (``[problem] objective``).
        doc: one line of description.
        variables: variable name -> :class:`VariableInfo`.
        model: ``[model]`` key -> default value (SI); keys not listed are refused.
        outputs: names of the outputs ``build`` returns; the first is the objective.
        build: ``build(problem, discrete) -> evaluate`` where ``discrete`` maps each discrete
            variable to its value and ``evaluate(x)`` maps continuous variable name -> JAX
            scalar (SI) to output name -> JAX value (scalars; a ``"residuals"`` vector for
            the ``lm`` driver). ``evaluate`` must be differentiable in ``x``.
        requires_yield: the problem must have a ``[yield]`` table.
        check: ``check(problem, discrete, x)`` run once before a driver evaluates the
            objective at the start point ``x`` (continuous variable -> SI value/array):
            raises :class:`~encdesign.EncdesignInputError` naming the objective when it
            cannot be evaluated or differentiated (user objectives,
            :mod:`encdesign.design._user`). ``None``: no check.
    """

    name: str
    doc: str
    variables: Mapping[str, VariableInfo]
    model: Mapping[str, Any]
    outputs: tuple[str, ...]
    build: Callable[[Any, dict[str, Any]], Callable[[dict[str, Any]], dict[str, Any]]]
    requires_yield: bool = False
    check: Callable[[Any, dict[str, Any], dict[str, Any]], None] | None = dataclasses.field(
        default=None, compare=False
    )
