"""Design problems: variables, objective, constraints, yield target — apart from drivers.

A *problem* says what to vary and what to minimise; a *driver* (:mod:`encdesign.design._drivers`)
says how. Problems are written as TOML files (``encdesign optimize PROBLEM.toml``)::

    [problem]
    name = "reference head of a 3+1 encoder"
    objective = "cotangent_sensitivity"   # a name in the objective registry
    sense = "minimize"                    # or "maximize"
    seed = 0                              # PRNG seed of any Monte Carlo inside

    [model]                               # fixed settings of the objective (SI units)
    n_heads = 3
    max_order = 16

    [variables.reference_angle]           # a continuous variable
    units = "deg"                         # units of start/lower/upper in this file
    start = 20.0
    lower = 5.0
    upper = 55.0

    [variables.pole_pairs]                # a discrete variable: enumerated
    values = [4, 5, 6, 7]

    [constraints.residual_rms]            # bound on another output of the objective
    upper = 1e-6

    [yield]                               # optional: a yield target for Monte Carlo builds
    target = 0.99
    spec = 1.0
    spec_units = "urad"
    n_builds = 2000

    [driver]
    kind = "lbfgsb"                       # bfgs | lbfgsb | lm | grid | lhs
    max_steps = 200

``[driver]`` (and ``[sweep]``, ``grid`` or ``lhs``) parses into one driver object of
:mod:`encdesign.design._drivers` (:data:`~encdesign.design._drivers.DRIVERS`): its keys are
that driver's fields, and a key it does not take (``gtol`` under ``bfgs``) or a value it
cannot use is refused by name. ``penalty`` (the constraint penalty weight of
:func:`~encdesign.design.solve_problem`) is also accepted under ``bfgs`` and ``lbfgsb``.

Every name is checked against the objective's declaration in the registry
(:class:`ProblemObjective`); values are converted to SI on load. Bad files raise
:class:`~encdesign.EncdesignInputError` naming the file, the field, the value and what was
expected: an unknown variable, bounds that exclude the start point, an infeasible yield
target, a non-integer pole count, …
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import input_error
from ..io._recording import read_toml, show
from ._drivers import (
    DRIVERS,
    LBFGSB,
    TOL_MAX,
    AbstractDOE,
    AbstractDriver,
    Grid,
    LevenbergMarquardt,
    check_setting,
)
from ._registry import PROBLEM_OBJECTIVES
from ._spec import ProblemObjective as ProblemObjective
from ._spec import VariableInfo as VariableInfo
from ._spec import model_limit

# unit name -> (SI unit, factor to SI)
UNITS: dict[str, tuple[str, float]] = {
    "rad": ("rad", 1.0),
    "mrad": ("rad", 1e-3),
    "urad": ("rad", 1e-6),
    "nrad": ("rad", 1e-9),
    "deg": ("rad", math.pi / 180.0),
    "arcsec": ("rad", math.pi / 180.0 / 3600.0),
    "m": ("m", 1.0),
    "mm": ("m", 1e-3),
    "um": ("m", 1e-6),
    "nm": ("m", 1e-9),
    "s": ("s", 1.0),
    "ms": ("s", 1e-3),
    "us": ("s", 1e-6),
    "ns": ("s", 1e-9),
    "1": ("1", 1.0),
}

SEED_MAX = 2**63 - 1  # JAX keys take a 64-bit seed
MAX_GRID_POINTS = 10_000_000  # a grid beyond this does not fit in memory as one array

DRIVER_KINDS = tuple(DRIVERS)
SWEEP_KINDS = tuple(k for k, c in DRIVERS.items() if issubclass(c, AbstractDOE))
PENALTY = 1e4
"""Default constraint penalty weight (relative to ``|objective|`` at the start)."""
PENALISED = ("bfgs", "lbfgsb")
"""The drivers that take ``penalty`` in a problem file (their solves penalise constraints)."""
_TOP_KEYS = {"problem", "model", "variables", "constraints", "yield", "driver", "sweep"}


def to_si(value: float, units: str, where: str, si_units: str | None = None) -> float:
    """Convert ``value`` in ``units`` to SI; check the dimension against ``si_units``."""
    if units not in UNITS:
        raise input_error(where, f"unknown units {units!r}", f"one of {', '.join(UNITS)}")
    si, factor = UNITS[units]
    if si_units is not None and si != si_units:
        raise input_error(where, f"units {units!r} are not a unit of {si_units!r}")
    return float(value) * factor


@dataclasses.dataclass(frozen=True)
class Variable:
    """A design variable of a problem (all values SI).

    Attributes:
        name: variable name.
        units: units used in the problem file (for display).
        si_units: SI unit.
        start: start value (continuous) or first value (discrete), SI.
        lower, upper: bounds, SI (``±inf`` when not given).
        values: allowed values of a discrete variable (``None`` for continuous), SI.
        integer: values are integers.
        group: for an element ``name[i]`` of a vector variable, the vector's name (the
            objective receives the elements stacked into one 1-D array); ``None`` for a
            scalar.
        index: the element's position in its vector.
    """

    name: str
    units: str
    si_units: str
    start: float
    lower: float = -math.inf
    upper: float = math.inf
    values: tuple[float, ...] | None = None
    integer: bool = False
    group: str | None = None
    index: int = 0

    @property
    def discrete(self) -> bool:
        """True for an enumerated variable."""
        return self.values is not None

    @property
    def choices(self) -> tuple[float, ...]:
        """The allowed values of a discrete variable (empty for a continuous one), SI."""
        return self.values if self.values is not None else ()

    @property
    def scale(self) -> float:
        """A typical size used to normalise the variable for solvers (SI)."""
        if math.isfinite(self.lower) and math.isfinite(self.upper) and self.upper > self.lower:
            return self.upper - self.lower
        return abs(self.start) if self.start != 0 else 1.0

    def display(self, value_si: float) -> float:
        """``value_si`` converted to the file's units."""
        return value_si / UNITS[self.units][1]


@dataclasses.dataclass(frozen=True)
class Constraint:
    """Bound on an output: ``lower <= output <= upper`` (SI)."""

    output: str
    lower: float = -math.inf
    upper: float = math.inf


@dataclasses.dataclass(frozen=True)
class YieldTarget:
    """Yield requirement: at least ``target`` of ``n_builds`` Monte Carlo builds have their
    error metric ``<= spec`` (SI, e.g. rad)."""

    target: float
    spec: float
    n_builds: int


@dataclasses.dataclass(frozen=True)
class Problem:
    """A validated design problem (see the module docstring for the file format).

    Attributes:
        name: title.
        objective: the registry entry.
        sense: ``"minimize"`` or ``"maximize"``.
        model: fixed settings (registry defaults overridden by the file), SI.
        variables: the design variables in file order.
        constraints: output bounds.
        yield_target: the ``[yield]`` table or ``None``.
        driver: the ``[driver]`` (default :class:`~encdesign.design.LBFGSB`).
        sweep: the ``[sweep]`` design of experiments for ``encdesign sweep`` (default
            :class:`~encdesign.design.Grid`).
        seed: PRNG seed.
        path: the file (``None`` when built in memory).
    """

    name: str
    objective: ProblemObjective
    sense: str
    model: dict[str, Any]
    variables: tuple[Variable, ...]
    constraints: tuple[Constraint, ...] = ()
    yield_target: YieldTarget | None = None
    driver: AbstractDriver = dataclasses.field(default_factory=LBFGSB)
    sweep: AbstractDOE = dataclasses.field(default_factory=Grid)
    seed: int = 0
    path: Path | None = None
    penalty: float = PENALTY
    """Constraint penalty weight of a gradient solve, relative to ``|objective|`` at the
    start (``[driver] penalty``)."""

    @property
    def continuous(self) -> tuple[Variable, ...]:
        """The continuous variables."""
        return tuple(v for v in self.variables if not v.discrete)

    @property
    def discrete(self) -> tuple[Variable, ...]:
        """The enumerated variables."""
        return tuple(v for v in self.variables if v.discrete)


MAX_MAGNITUDE_SI = 1e12
"""Largest magnitude of a continuous variable's start or bound, in SI units: beyond it a
value is a typing slip (``upper = 1e300`` degrees), not a design."""


def _where(path: Path | str, *keys: str) -> str:
    return f"{path}: " + ".".join(keys) if keys else str(path)


def _num(value: object, where: str, what: str = "a number") -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise input_error(where, f"{show(value)[:60]} is not a number", what)
    if not math.isfinite(float(value)):
        raise input_error(where, f"{show(value)} is not finite", what)
    return float(value)


def _bounded(value: object, where: str, what: str = "a number") -> float:
    """A finite number of magnitude at most :data:`MAX_MAGNITUDE_SI` (SI units)."""
    x = _num(value, where, what)
    if not abs(x) <= MAX_MAGNITUDE_SI:
        raise input_error(where, f"{show(value)}", f"|value| <= {MAX_MAGNITUDE_SI:g} (SI units)")
    return x


def _check_keys(table: Mapping[str, object], allowed: set[str], where: str) -> None:
    for k in table:
        if k not in allowed:
            raise input_error(where, f"unknown key {k!r}", f"one of {', '.join(sorted(allowed))}")


def _variable(name: str, table: object, info: VariableInfo, src: str) -> Variable:
    where = _where(src, "variables", name)
    if not isinstance(table, Mapping):
        raise input_error(where, f"{table!r} is not a table", "a [variables.NAME] table")
    _check_keys(table, {"units", "start", "lower", "upper", "values"}, where)
    units = table.get("units", info.units)
    if not isinstance(units, str):
        raise input_error(f"{where}.units", f"{units!r} is not a string")
    to_si(1.0, units, f"{where}.units", info.units)
    factor = UNITS[units][1]
    if info.discrete or "values" in table:
        if not info.discrete:
            raise input_error(where, "has 'values' but is a continuous variable", "start/bounds")
        for k in ("start", "lower", "upper"):
            if k in table:
                raise input_error(f"{where}.{k}", "given for a discrete variable", "values only")
        vals = table.get("values")
        if not isinstance(vals, list) or not vals:
            raise input_error(f"{where}.values", f"{vals!r}", "a non-empty list of values")
        out = []
        for i, v in enumerate(vals):
            w = f"{where}.values[{i}]"
            x = _num(v, w, "an integer" if info.integer else "a number")
            if info.integer and (not isinstance(v, int) or x != round(x)):
                raise input_error(w, f"{v!r} is not an integer", f"an integer {name}")
            xs = x * factor
            if not info.lower <= xs <= info.upper:
                raise input_error(w, f"{v!r} outside [{info.lower}, {info.upper}] (SI)")
            limit = model_limit(name)  # a count named like a [model] setting (n_builds …)
            if limit is not None and not limit.admits(int(xs) if info.integer else xs):
                raise input_error(w, f"{show(v)}", limit.describe())
            out.append(int(x) if info.integer else xs)
        if len(set(out)) != len(out):
            raise input_error(f"{where}.values", f"{vals!r} has repeated values", "distinct")
        if info.values is not None:
            allowed = [float(a) for a in info.values]
            for i, x in enumerate(out):
                if not any(math.isclose(float(x), a, rel_tol=1e-12, abs_tol=0.0) for a in allowed):
                    raise input_error(
                        f"{where}.values[{i}]",
                        f"{vals[i]!r} is not a declared value of {name!r}",
                        f"one of {', '.join(str(v) for v in info.values)} (SI)",
                    )
        return Variable(name, units, info.units, out[0], values=tuple(out), integer=info.integer)
    if "start" not in table and info.start is None:
        raise input_error(where, "no 'start'", "a start value")
    if "start" in table:
        start = _num(table["start"], f"{where}.start") * factor
    else:
        start = float(info.start)
    for k in ("start", "lower", "upper"):
        if k in table and not abs(_num(table[k], f"{where}.{k}") * factor) <= MAX_MAGNITUDE_SI:
            raise input_error(
                f"{where}.{k}",
                f"{show(table[k])} {units}",
                f"|value| <= {MAX_MAGNITUDE_SI:g} in SI units ({info.units})",
            )
    lower = _num(table["lower"], f"{where}.lower") * factor if "lower" in table else info.lower
    upper = _num(table["upper"], f"{where}.upper") * factor if "upper" in table else info.upper
    if not lower < upper:
        raise input_error(where, f"lower {lower} >= upper {upper} (SI)", "lower < upper")
    if lower < info.lower or upper > info.upper:
        raise input_error(
            where,
            f"bounds [{lower}, {upper}] leave the valid range [{info.lower}, {info.upper}] (SI)",
        )
    if not lower <= start <= upper:
        raise input_error(
            f"{where}.start",
            f"start {table['start']} {units} is outside the bounds "
            f"[{table.get('lower', lower / factor)}, {table.get('upper', upper / factor)}] {units}",
            "lower <= start <= upper",
        )
    if info.check is not None:
        info.check(start, f"{where}.start")
    return Variable(name, units, info.units, start, lower, upper)


def _vector_variable(name: str, table: object, info: VariableInfo, src: str) -> list[Variable]:
    """The elements ``name[i]`` of a vector variable (``start`` a list; ``lower``/``upper``
    a number or a list of the same length), each checked like a scalar variable, then the
    whole start vector by ``info.check``."""
    where = _where(src, "variables", name)
    if not isinstance(table, Mapping):
        raise input_error(where, f"{table!r} is not a table", "a [variables.NAME] table")
    _check_keys(table, {"units", "start", "lower", "upper"}, where)
    units = table.get("units", info.units)
    if not isinstance(units, str):
        raise input_error(f"{where}.units", f"{units!r} is not a string")
    to_si(1.0, units, f"{where}.units", info.units)
    factor = UNITS[units][1]
    if "start" in table:
        start = table["start"]
    elif info.start is not None:  # the declared default is SI
        start = [float(v) / factor for v in info.start]
    else:
        raise input_error(where, "no 'start'", "a list of start values")
    if not isinstance(start, list | tuple) or not start:
        raise input_error(f"{where}.start", f"{start!r}", "a non-empty list of start values")
    n = len(start)
    if info.size and n != info.size:
        raise input_error(f"{where}.start", f"{n} values", f"{info.size} values")
    per: dict[str, list[Any]] = {}
    for k in ("lower", "upper"):
        v = table.get(k)
        if isinstance(v, list | tuple):
            if len(v) != n:
                raise input_error(f"{where}.{k}", f"{len(v)} values", f"{n} (one per element)")
            per[k] = list(v)
        elif v is not None:
            per[k] = [v] * n
    scalar_info = dataclasses.replace(info, size=None, start=None, check=None)
    elems = []
    for i in range(n):
        sub = {"units": units, "start": start[i], **{k: per[k][i] for k in per}}
        v = _variable(f"{name}[{i}]", sub, scalar_info, src)
        elems.append(dataclasses.replace(v, group=name, index=i))
    if info.check is not None:
        info.check(np.array([e.start for e in elems]), f"{where}.start")
    return elems


def _user_objective(obj_name: object, registry: Mapping[str, ProblemObjective], where: str):
    """A user objective (``package.module:function`` or an entry-point name)."""
    from ._user import load_user_objective, registered_names

    expected = (
        f"one of {', '.join(sorted(registry))}, a 'package.module:function' path, or a name "
        f"registered under the entry-point group 'encdesign.objectives'"
    )
    if not isinstance(obj_name, str) or not obj_name:
        raise input_error(where, f"unknown objective {obj_name!r}", expected)
    try:
        return load_user_objective(obj_name, where)
    except KeyError:
        names = registered_names()
        raise input_error(
            where,
            f"unknown objective {obj_name!r}",
            expected + (f" (registered: {', '.join(names)})" if names else ""),
        ) from None


def parse_problem(
    data: Mapping[str, Any],
    registry: Mapping[str, ProblemObjective] | None = None,
    *,
    source: str | os.PathLike = "<problem>",
) -> Problem:
    """Validate a problem given as a dict (the TOML content) and return a :class:`Problem`.

    Args:
        data: the parsed TOML.
        registry: objective name -> :class:`ProblemObjective` (default: the objectives of
            :mod:`encdesign.objectives`).
        source: name used in error messages (the file path).
    """
    if registry is None:
        registry = PROBLEM_OBJECTIVES
    src = str(source)
    if not isinstance(data, Mapping):
        raise input_error(src, "not a TOML table")
    _check_keys(data, _TOP_KEYS, src)
    for key in _TOP_KEYS:
        if key in data and not isinstance(data[key], Mapping):
            raise input_error(
                _where(src, key), f"{show(data[key])[:60]} is not a table", f"a [{key}] table"
            )
    head = data.get("problem")
    if not isinstance(head, Mapping):
        raise input_error(src, "no [problem] table", "[problem] with name and objective")
    _check_keys(head, {"name", "objective", "sense", "seed", "description"}, f"{src}: problem")
    obj_name = head.get("objective")
    if isinstance(obj_name, str) and obj_name in registry:
        spec = registry[obj_name]
    else:
        spec = _user_objective(obj_name, registry, _where(src, "problem", "objective"))
    sense = head.get("sense", "minimize")
    if sense not in ("minimize", "maximize"):
        raise input_error(_where(src, "problem", "sense"), f"{sense!r}", "minimize or maximize")
    seed = head.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= SEED_MAX:
        raise input_error(
            _where(src, "problem", "seed"), f"{show(seed)}", f"an integer 0 … {SEED_MAX} (2^63-1)"
        )
    model = dict(spec.model)
    for k, v in dict(data.get("model", {})).items():
        if k not in spec.model:
            raise input_error(
                _where(src, "model", k),
                f"unknown model setting {k!r} for objective {obj_name!r}",
                f"one of {', '.join(sorted(spec.model)) or 'none'}",
            )
        default = spec.model[k]
        if isinstance(default, bool):
            ok = isinstance(v, bool)
        elif isinstance(default, int):
            ok = isinstance(v, int) and not isinstance(v, bool)
        elif isinstance(default, float):
            ok = isinstance(v, int | float) and not isinstance(v, bool)
        elif isinstance(default, list | tuple):
            ok = isinstance(v, list)
        else:
            ok = isinstance(v, type(default))
        if not ok:
            raise input_error(
                _where(src, "model", k),
                f"{show(v)[:60]}",
                f"a value like {default!r} ({type(default).__name__})",
            )
        if isinstance(v, float) and not math.isfinite(v):
            raise input_error(
                _where(src, "model", k), f"{show(v)} is not finite", "a finite number"
            )
        limit = model_limit(k, spec)
        if limit is not None and not isinstance(v, bool | list | tuple) and not limit.admits(v):
            raise input_error(_where(src, "model", k), f"{show(v)}", limit.describe())
        model[k] = float(v) if isinstance(default, float) and isinstance(v, int | float) else v
    if "n_angles" in model and "max_order" in model:
        n_ang, order = int(model["n_angles"]), int(model["max_order"])
        if n_ang < 2 * order + 1:
            raise input_error(
                _where(src, "model", "n_angles"),
                f"{n_ang} angles cannot resolve max_order = {order}",
                f"n_angles >= 2 * max_order + 1 = {2 * order + 1}",
            )
    vtables = data.get("variables", {})
    if not isinstance(vtables, Mapping) or not vtables:
        raise input_error(src, "no [variables.*] tables", "at least one design variable")
    variables = []
    for name, table in vtables.items():
        if name not in spec.variables:
            raise input_error(
                _where(src, "variables", name),
                f"unknown variable {name!r} for objective {obj_name!r}",
                f"one of {', '.join(spec.variables)} (the variables it declares)",
            )
        info = spec.variables[name]
        if info.size is not None:
            variables.extend(_vector_variable(name, table, info, src))
        else:
            variables.append(_variable(name, table, info, src))
    constraints = []
    for out, table in dict(data.get("constraints", {})).items():
        where = _where(src, "constraints", out)
        if out not in spec.outputs:
            raise input_error(where, f"unknown output {out!r}", f"one of {', '.join(spec.outputs)}")
        if not isinstance(table, Mapping):
            raise input_error(where, f"{table!r} is not a table", "lower and/or upper")
        _check_keys(table, {"lower", "upper"}, where)
        lo = _bounded(table["lower"], f"{where}.lower") if "lower" in table else -math.inf
        hi = _bounded(table["upper"], f"{where}.upper") if "upper" in table else math.inf
        if not lo < hi:
            raise input_error(where, f"lower {lo} >= upper {hi}", "lower < upper")
        constraints.append(Constraint(out, lo, hi))
    ytarget = None
    if "yield" in data:
        ytarget = _yield(data["yield"], src, spec.yield_units)
    elif spec.requires_yield:
        raise input_error(src, f"objective {obj_name!r} needs a [yield] table")
    driver, penalty = parse_driver(data.get("driver", {}), _where(src, "driver"), DRIVER_KINDS)
    sweep, _ = parse_driver(data.get("sweep", {}), _where(src, "sweep"), SWEEP_KINDS, "grid")
    assert isinstance(sweep, AbstractDOE)
    n_cont = sum(not v.discrete for v in variables)
    for drv, label in ((driver, "driver"), (sweep, "sweep")):
        if isinstance(drv, Grid) and n_cont:
            ppd = drv.points_per_dim
            if ppd**n_cont > MAX_GRID_POINTS:
                raise input_error(
                    _where(src, label, "points_per_dim"),
                    f"{ppd}^{n_cont} = {ppd**n_cont:.3g} grid points",
                    f"at most {MAX_GRID_POINTS} points "
                    f"(points_per_dim <= {int(MAX_GRID_POINTS ** (1 / n_cont) + 1e-9)})",
                )
    if isinstance(driver, LevenbergMarquardt) and "residuals" not in spec.outputs:
        raise input_error(
            _where(src, "driver", "kind"),
            f"'lm' needs a residual vector but objective {obj_name!r} has none",
            "bfgs, lbfgsb, grid or lhs",
        )
    name = head.get("name", Path(src).stem)
    if not isinstance(name, str) or not name.strip():
        raise input_error(
            _where(src, "problem", "name"), f"{show(name)[:60]}", "a non-empty string"
        )
    return Problem(
        str(name),
        spec,
        sense,
        model,
        tuple(variables),
        tuple(constraints),
        ytarget,
        driver,
        sweep,
        seed,
        None if src == "<problem>" else Path(src),
        penalty,
    )


def _yield(table: object, src: str, si_units: str = "rad") -> YieldTarget:
    where = _where(src, "yield")
    if not isinstance(table, Mapping):
        raise input_error(where, f"{table!r} is not a table", "target, spec, n_builds")
    _check_keys(table, {"target", "spec", "spec_units", "n_builds"}, where)
    for k in ("target", "spec"):
        if k not in table:
            raise input_error(where, f"no {k!r}", "target, spec and n_builds")
    target = _num(table["target"], f"{where}.target")
    n = table.get("n_builds", 1000)
    if isinstance(n, bool) or not isinstance(n, int) or n < 10:
        raise input_error(f"{where}.n_builds", f"{n!r}", "an integer >= 10")
    if not 0.0 < target < 1.0:
        raise input_error(
            f"{where}.target",
            f"infeasible yield target {target!r}: no Monte Carlo estimate can show it",
            "a fraction strictly between 0 and 1",
        )
    if (1.0 - target) * n < 1.0:
        raise input_error(
            f"{where}.target",
            f"infeasible yield target {target!r} with n_builds = {n}: fewer than one "
            f"failing build is allowed, so the target cannot be told apart from 100 %",
            f"n_builds >= {math.ceil(1.0 / (1.0 - target))} or a lower target",
        )
    units = table.get("spec_units", si_units)
    if not isinstance(units, str):
        raise input_error(f"{where}.spec_units", f"{show(units)} is not a string", "a unit name")
    spec = _num(table["spec"], f"{where}.spec")
    spec_si = to_si(spec, units, f"{where}.spec_units", si_units)
    if not 0.0 < spec_si <= MAX_MAGNITUDE_SI:
        raise input_error(
            f"{where}.spec",
            f"{show(spec)} {units}",
            f"a positive accuracy spec of at most {MAX_MAGNITUDE_SI:g} {si_units}",
        )
    return YieldTarget(target, spec_si, int(n))


def parse_driver(
    table: object, where: str, kinds: tuple[str, ...] = DRIVER_KINDS, default: str = "lbfgsb"
) -> tuple[AbstractDriver, float]:
    """The driver a ``[driver]`` (or ``[sweep]``) table names, and the penalty weight.

    ``kind`` picks the driver (:data:`~encdesign.design._drivers.DRIVERS`, one of
    ``kinds``; ``default`` when absent); every other key must be one of that driver's
    fields (or ``penalty`` under :data:`PENALISED` drivers) and a value it can use. Errors
    name ``where`` (the file and table), the key and what was expected.
    """
    if not isinstance(table, Mapping):
        raise input_error(where, f"{show(table)[:60]} is not a table", "a table")
    kind = table.get("kind", default)
    if not isinstance(kind, str) or kind not in kinds:
        raise input_error(
            f"{where}.kind", f"unknown driver {show(kind)}", f"one of {', '.join(kinds)}"
        )
    cls = DRIVERS[kind]
    fields = {f.name for f in dataclasses.fields(cls)}
    extra = {"penalty"} if kind in PENALISED else set()
    for k in table:
        if k != "kind" and k not in fields | extra:
            raise input_error(
                f"{where}.{k}",
                f"{k!r} is not a setting of the {kind!r} driver ({cls.__name__})",
                f"one of {', '.join(sorted(fields | extra))}",
            )
    settings: dict[str, Any] = {}
    for k, v in table.items():
        if k in fields:
            number, lo, hi = cls.limits[k]
            check_setting(f"{where}.{k}", v, number, lo, hi)
            settings[k] = number(v)
    penalty = PENALTY
    if "penalty" in table:
        check_setting(f"{where}.penalty", table["penalty"], float, 0.0, TOL_MAX)
        penalty = float(table["penalty"])
    return cls(**settings), penalty


def load_problem(
    path: str | os.PathLike, registry: Mapping[str, ProblemObjective] | None = None
) -> Problem:
    """Read and validate a problem TOML file (never modified).

    Raises :class:`~encdesign.EncdesignInputError` naming the file and field on bad input.
    """
    path = Path(path)
    return parse_problem(read_toml(path), registry, source=path)
