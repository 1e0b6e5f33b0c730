"""The design results in a notebook: the ``_repr_html_`` of :class:`Solution`,
:class:`MonteCarloResult`, :class:`DOEResult`, :class:`EnumerationResult` and
:class:`ProblemResult`, built from the report's HTML pieces (``encdesign/_html.py``): the
status as a badge with its message, then the key numbers. Every value is escaped."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

from .._html import array_cell, escape, num, result_html, status_badge, table
from ._spec import ProblemObjective
from ._status import DriverStatus

# What each display reads of its result. Protocols, not the result classes: those import
# this module (their ``_repr_html_``), and this module imports none of them back.


class _Outcome(Protocol):
    """A status and an objective (a solution, a combination's inner result)."""

    @property
    def status(self) -> DriverStatus: ...
    @property
    def objective(self) -> float: ...


class _Reported(Protocol):
    """Any design result: a status and the driver's account of it."""

    @property
    def status(self) -> DriverStatus: ...
    @property
    def message(self) -> str: ...


class _SolutionView(_Reported, Protocol):
    @property
    def objective(self) -> float: ...
    @property
    def n_steps(self) -> int: ...
    @property
    def at_bounds(self) -> tuple[str, ...]: ...
    @property
    def value(self) -> np.ndarray: ...
    @property
    def solver(self) -> str: ...


class _MonteCarloView(_Reported, Protocol):
    @property
    def values(self) -> np.ndarray: ...
    @property
    def n(self) -> int: ...
    @property
    def mean(self) -> float: ...
    @property
    def stderr(self) -> float: ...
    @property
    def std(self) -> float: ...
    @property
    def n_nonfinite(self) -> int: ...


class _DOEView(_Reported, Protocol):
    @property
    def values(self) -> np.ndarray: ...
    @property
    def best_index(self) -> int: ...
    @property
    def best_value(self) -> float: ...
    @property
    def best_point(self) -> np.ndarray: ...


class _EnumerationView(_Reported, Protocol):
    @property
    def choices(self) -> Sequence[Mapping[str, object]]: ...
    @property
    def solutions(self) -> Sequence[_Outcome]: ...
    @property
    def best_index(self) -> int: ...
    @property
    def best_choice(self) -> Mapping[str, object]: ...


class _ProblemView(Protocol):
    @property
    def name(self) -> str: ...
    @property
    def sense(self) -> str: ...
    @property
    def objective(self) -> ProblemObjective: ...
    @property
    def driver(self) -> object: ...


class _DesignView(_Outcome, Protocol):
    @property
    def discrete(self) -> Mapping[str, object]: ...
    @property
    def inputs(self) -> Mapping[str, float]: ...
    @property
    def outputs(self) -> Mapping[str, float]: ...
    @property
    def n_steps(self) -> int: ...


class _ProblemResultView(_Reported, Protocol):
    @property
    def problem(self) -> _ProblemView: ...
    @property
    def best(self) -> _DesignView | None: ...
    @property
    def results(self) -> Sequence[_DesignView]: ...


class _RareEventView(_Reported, Protocol):
    @property
    def betas(self) -> np.ndarray: ...
    @property
    def failure_prob(self) -> float: ...
    @property
    def failure_stderr(self) -> float: ...
    @property
    def form_failure_prob(self) -> float: ...
    @property
    def n_builds(self) -> int: ...
    @property
    def n_form_builds(self) -> int: ...
    @property
    def n_failures(self) -> int: ...
    @property
    def lr_gradient(self) -> np.ndarray | None: ...
    @property
    def lr_gradient_stderr(self) -> np.ndarray | None: ...
    @property
    def names(self) -> tuple[str, ...] | None: ...


def _headline(r: _Reported) -> str:
    """The status badge, what the status means, and the driver's own account."""
    status = r.status
    meaning = getattr(status, "message", "")
    text = status_badge(status, bool(status.ok))
    if meaning:
        text += f" {escape(meaning)}"
    message = getattr(r, "message", "")
    if message and message != meaning:
        text += f'<br><span class="small">{escape(message)}</span>'
    return text


def solution_html(s: _SolutionView) -> str:
    """A :class:`~encdesign.design.Solution`: objective, steps, bounds touched, the value."""
    fields = [
        ("objective", num(s.objective, 8)),
        ("steps", num(s.n_steps)),
        ("on a bound", escape(", ".join(s.at_bounds)) or "none"),
        ("value", array_cell(s.value)),
    ]
    return result_html(f"Solution ({s.solver})", _headline(s), fields)


def monte_carlo_html(r: _MonteCarloView) -> str:
    """A :class:`~encdesign.design.MonteCarloResult`: mean ± standard error, spread and the
    5 / 50 / 95 % percentiles of the per-build values."""
    vals = np.asarray(r.values, dtype=np.float64)
    finite = vals[np.isfinite(vals)]
    pct = (
        [num(float(np.percentile(finite, q)), 6) for q in (5, 50, 95)] if finite.size else ["-"] * 3
    )
    fields = [
        ("builds", num(r.n)),
        ("mean", f"{num(r.mean, 6)} ± {num(r.stderr, 3)} (standard error)"),
        ("standard deviation", num(r.std, 6)),
        ("percentiles 5 / 50 / 95 %", " / ".join(pct)),
        ("non-finite builds", num(r.n_nonfinite)),
    ]
    return result_html("Monte Carlo", _headline(r), fields)


def doe_html(r: _DOEView) -> str:
    """A :class:`~encdesign.design.DOEResult`: points, how many finite, the best point."""
    vals = np.asarray(r.values, dtype=np.float64)
    best = r.best_index >= 0
    fields = [
        ("points", num(len(vals))),
        ("finite values", num(int(np.isfinite(vals).sum()))),
        ("best index", num(r.best_index) if best else "none"),
        ("best value", num(r.best_value, 8) if best else "-"),
        ("best point", array_cell(r.best_point) if best else "-"),
    ]
    return result_html("Design of experiments", _headline(r), fields)


def enumeration_html(r: _EnumerationView) -> str:
    """An :class:`~encdesign.design.EnumerationResult`: one row per combination (its status
    and objective), the best marked."""
    rows = [
        [
            ("<b>best</b> " if i == r.best_index else "") + _choice(c),
            status_badge(s.status, bool(s.status.ok)),
            num(s.objective, 8),
        ]
        for i, (c, s) in enumerate(zip(r.choices, r.solutions))
    ]
    fields = [("combinations", num(len(r.choices)))]
    if r.best_index >= 0:
        fields.append(("best", _choice(r.best_choice)))
    sections = [table(["combination", "status", "objective"], rows, "combinations")]
    return result_html("Enumeration", _headline(r), fields, sections)


def _choice(d: Mapping[str, object]) -> str:
    """``k = v, ...`` of a discrete combination, escaped."""
    return escape(", ".join(f"{k} = {v}" for k, v in d.items()))


def _values(d: Mapping[str, float]) -> str:
    return table(["name", "value (SI)"], [[escape(k), array_cell(v)] for k, v in d.items()])


def problem_html(r: _ProblemResultView) -> str:
    """A :class:`~encdesign.design.ProblemResult`: the problem, the best design (inputs and
    outputs) and every discrete combination's status and objective."""
    p = r.problem
    fields = [
        ("objective", f"{escape(p.sense)} {escape(p.objective.name)}"),
        ("driver", escape(getattr(p.driver, "kind", type(p.driver).__name__))),
    ]
    sections = []
    if r.best is not None:
        b = r.best
        sign = -1.0 if p.sense == "maximize" else 1.0
        fields.append(("best objective", num(sign * b.objective, 8)))
        if b.discrete:
            fields.append(("best discrete", _choice(b.discrete)))
        sections += ["<p>best design: inputs</p>", _values(b.inputs)]
        sections += ["<p>best design: outputs</p>", _values(b.outputs)]
    if len(r.results) > 1:
        rows = [
            [
                _choice(x.discrete) or "-",
                status_badge(x.status, bool(x.status.ok)),
                num(x.objective, 8) if math.isfinite(x.objective) else "-",
                num(x.n_steps),
            ]
            for x in r.results
        ]
        sections += [table(["discrete", "status", "objective", "steps"], rows, "results")]
    return result_html(f"Problem {p.name}", _headline(r), fields, sections)


def rare_event_html(r: _RareEventView) -> str:
    """A :class:`~encdesign.design.RareEventResult`: the failure probability with its standard
    error, FORM's own estimate, the design points and the builds spent."""
    betas = np.asarray(r.betas, dtype=np.float64)
    fields = [
        ("failure probability", f"{num(r.failure_prob, 6)} ± {num(r.failure_stderr, 3)}"),
        ("FORM estimate Φ(−β_min)", num(r.form_failure_prob, 6)),
        ("design points", num(len(betas))),
        ("reliability indices β", array_cell(betas, 4)),
        ("builds (importance / FORM)", f"{num(r.n_builds)} / {num(r.n_form_builds)}"),
        ("builds in the failure region", num(r.n_failures)),
    ]
    if r.lr_gradient is not None:
        names = r.names or [str(i) for i in range(len(r.lr_gradient))]
        se = r.lr_gradient_stderr if r.lr_gradient_stderr is not None else [None] * len(names)
        grad = table(
            ["group", "dP_f/dσ", "standard error"],
            [[escape(n), num(g, 4), num(s, 3)] for n, g, s in zip(names, r.lr_gradient, se)],
        )
        return result_html("Rare-event yield", _headline(r), fields, [grad])
    return result_html("Rare-event yield", _headline(r), fields)
