"""What an objective declares to problem files: its variables and its registry entry.

Kept apart from :mod:`encdesign.design._problem` (which parses problem files) and
:mod:`encdesign.design._objectives` (which implements the built-in objectives) so that
both can import it and neither imports the other in a circle.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

SI_UNITS = ("rad", "m", "s", "1")
"""The SI units a variable is declared in (problem files may use any unit of the same
dimension, :data:`encdesign.design._problem.UNITS`)."""


class YieldSpec(Protocol):
    """What a builder reads of a problem's ``[yield]`` table (a
    :class:`~encdesign.design.YieldTarget`)."""

    @property
    def target(self) -> float: ...
    @property
    def spec(self) -> float: ...
    @property
    def n_builds(self) -> int: ...


class ProblemView(Protocol):
    """What an objective's ``build`` and ``check`` read of a problem (a
    :class:`~encdesign.design.Problem`; kept a protocol here so that this module imports
    none of the modules that use it)."""

    @property
    def name(self) -> str: ...
    @property
    def objective(self) -> ProblemObjective: ...
    @property
    def model(self) -> Mapping[str, Any]: ...
    @property
    def seed(self) -> int: ...
    @property
    def yield_target(self) -> YieldSpec | None: ...
    @property
    def path(self) -> Path | None: ...


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
        model_limits: ``[model]`` key -> :class:`ModelLimit` (documented range), overriding
            :data:`DEFAULT_MODEL_LIMITS` for this objective.
        yield_units: SI unit of the error metric a ``[yield]`` spec bounds.
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
    build: Callable[[ProblemView, dict[str, Any]], Callable[[dict[str, Any]], dict[str, Any]]]
    requires_yield: bool = False
    model_limits: Mapping[str, ModelLimit] = dataclasses.field(default_factory=dict)
    yield_units: str = "rad"
    check: Callable[[ProblemView, dict[str, Any], dict[str, Any]], None] | None = dataclasses.field(
        default=None, compare=False
    )


@dataclasses.dataclass(frozen=True)
class ModelLimit:
    """The documented range of one ``[model]`` setting (SI).

    Attributes:
        lower, upper: allowed range (``lower_open``: ``lower`` itself excluded).
        units: SI unit of the value (for messages), ``"1"`` when dimensionless.
        choices: allowed values of a string setting.
    """

    lower: float = -math.inf
    upper: float = math.inf
    lower_open: bool = False
    units: str = "1"
    choices: tuple[str, ...] = ()

    def describe(self) -> str:
        """The range in words, e.g. ``"0 < value <= 10 m"``."""
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        unit = "" if self.units == "1" else f" {self.units}"
        lo = (
            "" if self.lower == -math.inf else f"{self.lower:g} {'<' if self.lower_open else '<='} "
        )
        hi = "" if self.upper == math.inf else f" <= {self.upper:g}"
        return f"{lo}value{hi}{unit}".strip()

    def admits(self, v: Any) -> bool:
        """Whether ``v`` lies in the range (or among the choices)."""
        if self.choices:
            return v in self.choices
        x = float(v)
        if not math.isfinite(x):
            return False
        if x < self.lower or (self.lower_open and x == self.lower):
            return False
        return x <= self.upper


_SIGMA_RAD = ModelLimit(lower=0.0, upper=1.0, units="rad")

DEFAULT_MODEL_LIMITS: dict[str, ModelLimit] = {
    "radius_m": ModelLimit(0.0, 10.0, lower_open=True, units="m"),
    "reference_angle_rad": ModelLimit(-2 * math.pi, 2 * math.pi, units="rad"),
    "tilt_rad": ModelLimit(-0.5, 0.5, units="rad"),
    "gap_m": ModelLimit(0.0, 1.0, lower_open=True, units="m"),
    "n_heads": ModelLimit(2, 1000),
    "max_order": ModelLimit(1, 10_000),
    "grating_orders": ModelLimit(0, 10_000),
    "axial_orders": ModelLimit(0, 10_000),
    "n_angles": ModelLimit(4, 10_000_000),
    "n_builds": ModelLimit(1, 10_000_000),
    "metric": ModelLimit(choices=("rms", "peak")),
    "percentile": ModelLimit(0.0, 100.0, lower_open=True),
    "smooth_width": ModelLimit(0.0, 10.0, lower_open=True),
    "chunk_size": ModelLimit(1, 1_000_000),
    "pole_pairs": ModelLimit(1, 1000),
    "n_sensors": ModelLimit(1, 1000),
    "marks_per_rev": ModelLimit(2, 100_000_000),
    "n_phi": ModelLimit(1, 1_000_000),
    "speed_ripple": ModelLimit(0.0, 1.0),
    "sigma_placement": _SIGMA_RAD,
}
"""Ranges of the ``[model]`` settings of the built-in objectives, by name. Settings without
an entry: ``sigma_*`` (a standard deviation) and ``cost_ref_*`` (a cost reference) must be
finite and >= 0; ``*_rad`` (an angle: an azimuth may be anywhere on the circle, or beyond
for a multi-turn setting) within +-1000 rad; every other number finite."""


def model_limit(name: str, objective: ProblemObjective | None = None) -> ModelLimit | None:
    """The range of ``[model]`` setting ``name`` (objective's own, then the defaults)."""
    if objective is not None and name in objective.model_limits:
        return objective.model_limits[name]
    if name in DEFAULT_MODEL_LIMITS:
        return DEFAULT_MODEL_LIMITS[name]
    if name.startswith("sigma_"):
        return ModelLimit(lower=0.0, upper=1.0)
    if name.startswith("cost_ref_"):
        return ModelLimit(lower=0.0, upper=1e6)
    if name.endswith("_rad"):  # an angle (an azimuth, a tilt): finite and not absurd
        return ModelLimit(lower=-1e3, upper=1e3, units="rad")
    return None
