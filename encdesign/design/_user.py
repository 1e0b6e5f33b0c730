"""Objective functions that users write: declaration, lookup, validation.

A problem file may name, besides the built-in objectives of
:data:`encdesign.objectives.PROBLEM_OBJECTIVES`,

* ``objective = "package.module:function"`` — imported with :mod:`importlib`; or
* a name that an installed package registers under the entry-point group
  ``encdesign.objectives`` (``[project.entry-points."encdesign.objectives"]`` in its
  ``pyproject.toml``: ``stiffness = "mypkg.objectives:stiffness"``).

The function has the signature ``function(x, discrete, model, key) -> dict``:

* ``x`` — continuous variable name -> JAX float64 array (scalar, or 1-D for a vector
  variable), SI;
* ``discrete`` — discrete variable name -> its value (int or float);
* ``model`` — the ``[model]`` table (declared defaults overridden by the file), SI;
* ``key`` — a JAX PRNG key from ``[problem] seed`` (use it for any Monte Carlo, e.g.
  :func:`encdesign.design.expected_value` or :func:`encdesign.design.map_builds`);

and returns a dict of outputs (JAX scalars; the first declared output is the objective,
the others may be constrained). It must be JAX-differentiable in ``x``.

It declares its variables with the :func:`objective_function` decorator::

    @encdesign.objective_function(
        variables={
            "gap": encdesign.variable("m", lower=0.2e-3, upper=2e-3, start=1e-3),
            "n_heads": encdesign.variable("1", values=[2, 3, 4]),
        },
        outputs=("rms_rad", "cost"),
        model={"radius_m": 0.0254},
    )
    def my_objective(x, discrete, model, key): ...

or, without importing encdesign in the module, with a companion declaration: a module
attribute ``<function>_declaration`` holding the same keyword arguments as a dict.

Problems naming a user objective are validated against the declaration (unknown variables,
units of the wrong dimension, bounds outside the declared ones, values not among the
declared discrete values). Before a driver runs, :func:`check_user_objective` evaluates the
function once at the start point and raises :class:`~encdesign.EncdesignInputError`
naming the function if it fails, returns no dict, lacks a declared output, returns a
non-finite value, or cannot be differentiated (the CLI exits 2).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import EncdesignInputError, input_error
from .._usercode import user_code
from ._spec import SI_UNITS, ProblemObjective, ProblemView, VariableInfo

__all__ = [
    "ENTRY_POINT_GROUP",
    "UserDeclaration",
    "objective_function",
    "variable",
    "load_user_objective",
    "check_user_objective",
    "registered_names",
]

ENTRY_POINT_GROUP = "encdesign.objectives"
_ATTR = "__encdesign_declaration__"


def variable(
    units: str = "1",
    *,
    lower: float = -math.inf,
    upper: float = math.inf,
    start: float | Sequence[float] | None = None,
    values: Sequence[float] | None = None,
    integer: bool | None = None,
    size: int | None = None,
    doc: str = "",
) -> VariableInfo:
    """Declare a design variable of a user objective.

    Args:
        units: SI unit (``"rad"``, ``"m"``, ``"s"`` or ``"1"``); problem files may give
            values in any unit of that dimension.
        lower, upper: limits (SI) that a problem's bounds must respect.
        start: default start value (SI) when a problem's table gives none.
        values: allowed values of a discrete variable (a problem lists a subset).
        integer: values are integers (default: all ``values`` are ints).
        size: for a vector variable, its length (``0``: any length >= 1).
        doc: one line of description.
    """
    if units not in SI_UNITS:
        raise EncdesignInputError(f"variable units {units!r}: expected an SI unit (rad, m, s or 1)")
    vals = None if values is None else tuple(values)
    if integer is None:
        integer = vals is not None and all(isinstance(v, int) for v in vals)
    st = None if start is None else (tuple(start) if isinstance(start, Sequence) else start)
    return VariableInfo(
        units,
        discrete=vals is not None,
        integer=bool(integer),
        lower=lower,
        upper=upper,
        doc=doc,
        values=vals,
        start=st,
        size=size,
    )


@dataclasses.dataclass(frozen=True)
class UserDeclaration:
    """What a user objective declares (see :func:`objective_function`)."""

    variables: Mapping[str, VariableInfo]
    outputs: tuple[str, ...]
    model: Mapping[str, Any]
    doc: str = ""
    requires_yield: bool = False


def _declaration(
    variables: Mapping[str, Any],
    outputs: Sequence[str],
    model: Mapping[str, Any] | None,
    doc: str,
    requires_yield: bool,
    where: str,
) -> UserDeclaration:
    if not isinstance(variables, Mapping) or not variables:
        raise input_error(where, "declares no variables", "variables={name: variable(...)}")
    vs = {}
    for name, v in variables.items():
        if isinstance(v, Mapping):
            v = variable(**v)
        if not isinstance(v, VariableInfo):
            raise input_error(
                f"{where}: variables.{name}", f"{v!r}", "encdesign.variable(...) or a dict"
            )
        vs[str(name)] = v
    outs = tuple(str(o) for o in outputs) if not isinstance(outputs, str) else (outputs,)
    if not outs:
        raise input_error(where, "declares no outputs", "outputs=('objective', ...)")
    return UserDeclaration(vs, outs, dict(model or {}), str(doc), bool(requires_yield))


def objective_function(
    *,
    variables: Mapping[str, Any],
    outputs: Sequence[str],
    model: Mapping[str, Any] | None = None,
    doc: str = "",
    requires_yield: bool = False,
) -> Callable[[Callable], Callable]:
    """Decorator declaring a user objective ``function(x, discrete, model, key) -> dict``.

    Args:
        variables: variable name -> :func:`variable` (or a dict of its arguments).
        outputs: names of the outputs the function returns; the first is the objective.
        model: ``[model]`` keys the function accepts, with their defaults (SI).
        doc: one line of description (default: the function's docstring's first line).
        requires_yield: problems must have a ``[yield]`` table.
    """

    def wrap(fn: Callable) -> Callable:
        d = doc or (fn.__doc__ or "").strip().split("\n")[0]
        decl = _declaration(
            variables, outputs, model, d, requires_yield, getattr(fn, "__qualname__", "?")
        )
        setattr(fn, _ATTR, decl)
        return fn

    return wrap


_TRACING_ERRORS: tuple[type[BaseException], ...] = tuple(
    getattr(jax.errors, n)
    for n in (
        "ConcretizationTypeError",
        "TracerArrayConversionError",
        "TracerBoolConversionError",
        "TracerIntegerConversionError",
        "UnexpectedTracerError",
        "JAXTypeError",
        "JAXIndexError",
    )
    if isinstance(getattr(jax.errors, n, None), type)
)
"""JAX's errors about traced values: let through, the checks name them as 'not
differentiable' in the user's terms."""


def _resolve(name: str, where: str) -> tuple[Callable, str]:
    """The function and its ``module:function`` path for ``name``."""
    if ":" in name:
        mod_name, _, attr = name.partition(":")
        if not mod_name or not attr:
            raise input_error(where, f"objective path {name!r}", "'package.module:function'")
        try:
            with user_code(f"{where}: objective module {mod_name!r}", keep=(Exception,)):
                mod = importlib.import_module(mod_name)
        except EncdesignInputError:
            raise
        except Exception as exc:  # any import failure: name the module and the cause
            raise input_error(
                where,
                f"objective {name!r} does not import: {type(exc).__name__}: {exc}",
                "an importable 'package.module:function' (is the package on PYTHONPATH?)",
            ) from exc
        obj: Any = mod
        for part in attr.split("."):
            if not hasattr(obj, part):
                raise input_error(where, f"objective {name!r}: module {mod_name!r} has no {attr!r}")
            obj = getattr(obj, part)
        return obj, name
    eps = [ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
    if not eps:
        raise KeyError(name)
    ep = eps[0]
    try:
        with user_code(
            f"{where}: objective {name!r} (entry point {ep.value!r})", keep=(Exception,)
        ):
            fn = ep.load()
    except EncdesignInputError:
        raise
    except Exception as exc:
        raise input_error(
            where,
            f"objective {name!r} (entry point {ep.value!r} of group {ENTRY_POINT_GROUP!r}) "
            f"does not import: {type(exc).__name__}: {exc}",
        ) from exc
    return fn, ep.value


def registered_names() -> list[str]:
    """Names registered under the entry-point group ``encdesign.objectives``."""
    return sorted({ep.name for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)})


def load_user_objective(name: str, where: str = "problem.objective") -> ProblemObjective:
    """The :class:`~encdesign.design.ProblemObjective` of a user objective ``name``
    (``"package.module:function"`` or an entry-point name).

    Raises :class:`~encdesign.EncdesignInputError` naming ``name`` when it does not import,
    is not callable or has no declaration; :class:`KeyError` when ``name`` is neither a path
    nor a registered entry point.
    """
    fn, path = _resolve(name, where)
    if not callable(fn):
        raise input_error(where, f"objective {name!r} is a {type(fn).__name__}, not a function")
    decl = getattr(fn, _ATTR, None)
    if decl is None:
        mod = importlib.import_module(fn.__module__) if hasattr(fn, "__module__") else None
        comp = getattr(mod, f"{getattr(fn, '__name__', '')}_declaration", None) if mod else None
        if comp is None:
            raise input_error(
                where,
                f"objective {name!r} declares no variables",
                "the @encdesign.objective_function(...) decorator or a companion "
                f"'{getattr(fn, '__name__', 'function')}_declaration' dict",
            )
        if not isinstance(comp, Mapping):
            raise input_error(where, f"{path}_declaration is a {type(comp).__name__}", "a dict")
        try:
            decl = _declaration(
                comp.get("variables", {}),
                comp.get("outputs", ()),
                comp.get("model"),
                comp.get("doc", ""),
                comp.get("requires_yield", False),
                f"{path}_declaration",
            )
        except TypeError as exc:
            raise input_error(f"{path}_declaration", str(exc)) from exc

    def build(problem: ProblemView, discrete: dict[str, Any]) -> Callable[[dict[str, Any]], dict]:
        model = dict(problem.model)
        key = jax.random.key(problem.seed)
        disc = dict(discrete)

        def evaluate(x: dict[str, Any]) -> dict[str, Any]:
            with user_code(f"objective {path!r}", keep=_TRACING_ERRORS):
                out = fn(dict(x), dict(disc), dict(model), key)
            if not isinstance(out, Mapping):
                raise input_error(
                    f"objective {path!r}",
                    f"returned a {type(out).__name__}, not a dict of outputs",
                    f"a dict with {', '.join(decl.outputs)}",
                )
            missing = [o for o in decl.outputs if o not in out]
            if missing:
                raise input_error(
                    f"objective {path!r}",
                    f"returned no {', '.join(map(repr, missing))} (got {', '.join(out)})",
                    f"the declared outputs {', '.join(decl.outputs)}",
                )
            return {k: jnp.asarray(v, dtype=jnp.float64) for k, v in out.items()}

        return evaluate

    return ProblemObjective(
        name=name,
        doc=decl.doc,
        variables=decl.variables,
        model=decl.model,
        outputs=decl.outputs,
        build=build,
        requires_yield=decl.requires_yield,
        check=check_user_objective,
    )


def check_user_objective(problem: ProblemView, discrete: dict[str, Any], x: dict[str, Any]) -> None:
    """Evaluate a user objective once at ``x`` (SI, the start point) and differentiate it.

    Raises :class:`~encdesign.EncdesignInputError` naming the objective when it raises,
    returns no dict or misses an output, returns a non-finite or non-scalar value, or when
    ``jax.grad`` of its first output fails or is not finite.
    """
    evaluate = problem.objective.build(problem, dict(discrete))
    xj = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in x.items()}
    first = problem.objective.outputs[0]
    if xj:
        # the usual case in one compiled pass (an eager evaluation and an eager gradient
        # compile the objective's loops and scans anew, seconds for a Monte Carlo
        # objective); anything it refuses is looked at again eagerly below, which names it
        # in the user's terms (a traced value's type would be a JAX tracer's)

        def first_and_all(xx):
            out = evaluate(xx)
            return out[first], out

        try:
            (_, out), g = jax.jit(jax.value_and_grad(first_and_all, has_aux=True))(xj)
        except Exception:  # noqa: BLE001 - named by the eager look below
            pass
        else:
            if all(np.ndim(v) == 0 or k == "residuals" for k, v in out.items()) and all(
                np.all(np.isfinite(np.asarray(v))) for v in [*out.values(), *g.values()]
            ):
                return
    _check_eagerly(problem, evaluate, x, xj, first)


def _check_eagerly(problem: ProblemView, evaluate: Callable, x: dict, xj: dict, first: str) -> None:
    where = f"objective {problem.objective.name!r}"
    try:
        out = evaluate(xj)
    except EncdesignInputError:
        raise
    except Exception as exc:
        raise input_error(where, f"failed at the start point: {type(exc).__name__}: {exc}") from exc
    for k, v in out.items():
        arr = np.asarray(v)
        if arr.ndim != 0 and k != "residuals":
            raise input_error(where, f"output {k!r} has shape {arr.shape}", "a scalar")
        if not np.all(np.isfinite(arr)):
            raise input_error(
                where,
                f"output {k!r} is not finite ({arr.tolist()}) at the start point "
                f"{ {n: np.asarray(v).tolist() for n, v in x.items()} } (SI)",
                "finite outputs",
            )
    if not xj:
        return
    try:
        g = jax.grad(lambda xx: evaluate(xx)[first])(xj)
    except EncdesignInputError:
        raise
    except Exception as exc:
        raise input_error(
            where,
            f"is not differentiable in its continuous variables "
            f"({', '.join(xj)}): {type(exc).__name__}: {str(exc).splitlines()[0]}",
            "JAX operations on x (no float(), numpy or Python branches on x)",
        ) from exc
    for k, v in g.items():
        if not np.all(np.isfinite(np.asarray(v))):
            raise input_error(
                where, f"gradient of {first!r} with respect to {k!r} is not finite", "finite"
            )
