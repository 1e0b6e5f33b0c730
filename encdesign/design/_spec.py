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
    """

    units: str
    discrete: bool = False
    integer: bool = False
    lower: float = -math.inf
    upper: float = math.inf
    doc: str = ""


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
    """

    name: str
    doc: str
    variables: Mapping[str, VariableInfo]
    model: Mapping[str, Any]
    outputs: tuple[str, ...]
    build: Callable[[Any, dict[str, Any]], Callable[[dict[str, Any]], dict[str, Any]]]
    requires_yield: bool = False
