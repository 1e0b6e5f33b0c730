"""Candidate effects of the discrepancy finder: the registration API.

A candidate effect is a :class:`Candidate`: a differentiable JAX term that adds an error
(rad, or the kind's residual unit) to every sample and channel, the parameters it takes
(each a :class:`Param`, with its unit and shape), and its *signature*: the views of the
residual in which it shows (``docs/diagnose.md`` lists the views). The engine
(:mod:`encdesign.diagnose.engine._engine`) fits any candidate the same way: it evaluates
``fn`` and its Jacobian (``jax.jacfwd``) chunk by chunk over the rows, so a term only has
to be a pure function of its parameters and of the row columns.

Term function contract::

    fn(params: dict[str, Array], x: dict[str, Array]) -> Array  # shape (n, C)

``params`` maps each :class:`Param` name to an array of the shape given by
:meth:`Param.resolved_shape`; ``x`` holds the row columns of one chunk (``n`` rows) and the
recording constants (see :data:`ROW_COLUMNS` and :data:`CONSTANTS`). ``C`` is the number of
channels (heads of a multihead recording, 1 for a sensor against a reference or a motion
recording). No Python control flow on traced values; discrete choices go in the
:class:`Candidate` itself (it is a frozen dataclass, hashable: one compiled Jacobian per
candidate and chunk shape).

Users add their own candidate without editing the package: build a :class:`Candidate` and
pass it to :func:`encdesign.diagnose.diagnose` (``candidates=[...]``), or name a Python file
that defines ``CANDIDATES = [...]`` with ``encdesign diagnose --candidates FILE``
(``examples/custom_candidate.py``). There is no global registry (no mutable singleton).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ._settings import DEFAULT_SETTINGS, FinderSettings

ROW_COLUMNS = {
    "t": "time within the run, s",
    "tau": "global time (runs end to end in file order), s",
    "theta": "shaft angle (theta_ref, or the head mean), run angle offsets applied, rad",
    "theta_ref": "reference angle as recorded (zeros when absent), rad",
    "reading": "each channel's reading, rad, shape (n, C)",
    "run_onehot": "one-hot run membership, shape (n, R)",
    "omega": "steady speed of the sample's segment (signed), rad/s",
    "direction": "+1 / -1: direction of rotation of the sample's segment",
    "driver": "temp_c - mean (K) when a temperature column varies, else tau - mean (s)",
    "psi": "phase within one signal period (grating line, pole pair), rad, shape (n, C)",
}
"""Row columns the engine passes to every term (chunked along the first axis)."""

CONSTANTS = {
    "alpha": "nominal azimuth of each channel, rad, shape (C,)",
    "radius_m": "optical radius, m (1.0 when the recording gives none: lengths not reported)",
    "signal_periods": "signal periods per revolution (0 when unknown)",
    "n_runs": "number of runs (float scalar)",
}
"""Recording constants passed to every term (not chunked); a kind adds its own arrays
(``KindData.constants``, e.g. the sds sensor azimuths ``psi_m``)."""

SHAPES = ("1", "channels", "runs", "runs*channels", "orders", "channels*orders")


@dataclasses.dataclass(frozen=True)
class Param:
    """One named parameter (block) of a candidate.

    Attributes:
        name: parameter name, with its unit in it where it has one (``frequency_hz``).
        unit: SI unit (``"rad"``, ``"m"``, ``"Hz"``, ``"s"``, ``"1"``, ``"rad/K"``, ...).
        shape: ``"1"`` (scalar), ``"channels"``, ``"runs"``, ``"runs*channels"``, or a fixed
            tuple of ints.
        linear: whether the term is linear in it (then one Gauss-Newton step is exact and
            no start value is needed).
        scale: typical size (in ``unit``) used to scale the Jacobian column; ``None``: the
            engine scales each column to the residual's noise level.
        fit: ``False`` for a parameter held at its start value (e.g. a detected step size).
        description: one line for the report.
        global_time: a time on the finder's end-to-end axis ``tau`` (runs laid end to end,
            pauses removed; what the term reads): reported in the recording's own ``t``,
            with its ``run`` and interval (issue 44 C).
        first_run: the index of the first run of a change (held): reported with its
            interval of runs and the first row's time on the recording's own ``t``.
    """

    name: str
    unit: str
    shape: str | tuple[int, ...] = "1"
    linear: bool = True
    scale: float | None = None
    fit: bool = True
    description: str = ""
    global_time: bool = False
    first_run: bool = False

    def resolved_shape(self, n_channels: int, n_runs: int) -> tuple[int, ...]:
        """The array shape of this parameter for a recording of that size."""
        if isinstance(self.shape, tuple):
            return self.shape
        return {
            "1": (),
            "channels": (n_channels,),
            "runs": (n_runs,),
            "runs*channels": (n_runs, n_channels),
        }[self.shape]


@dataclasses.dataclass(frozen=True)
class Context:
    """What a candidate's hooks may look at (numpy, read-only).

    Attributes:
        kind: recording kind (``multihead``, ``motion``, ...).
        n_channels, n_runs: sizes.
        has_ref: whether the residual is against a reference angle (``theta_ref``).
        sensor: ``[encoder] sensor`` (``optical`` when absent).
        signal_periods: signal periods per revolution (0 when unknown).
        radius_m: optical radius or ``None``.
        rows: the row columns of :data:`ROW_COLUMNS` over the kept samples (numpy).
        consts: the constants of :data:`CONSTANTS` and the kind's own term constants
            (``KindData.constants``), built once in stage 1, read-only.
        noise: noise std per channel (difference-based estimate), residual unit.
        revolutions: revolutions covered per run.
        meta: the recording's TOML content.
        settings: the finder's thresholds (:class:`~encdesign.diagnose.FinderSettings`)
            this diagnosis runs with (a candidate's ``plausible`` rule may read them).
        max_order: the base model's highest order now (engine-owned: the engine builds a new
            context when it grows the base; 0 before the base is built).
        driver_name: what the ``driver`` row column is (``"temp_c"`` or ``"time"``;
            engine-owned).
        noise_info: what the kind's noise hook found beside the levels
            (``NoiseEstimate.info``; engine-owned, ``None`` before the noise stage).
        data: the kind's own data of this record (the
            :class:`~encdesign.diagnose.engine._protocol.KindData` its ``data()`` built,
            often the kind's subclass of it), read-only.
        orders_left_out: the integer orders above the base's that the base residual's
            ``orders`` view located where the base's order growth was tried and undone
            (engine-owned; empty where no growth was undone). The growth is undone where the
            grown base leaves much of what the views located (a step, say): those orders are
            then still in the residual, and a line among them is tested against them (the
            vibration's ``locked_margin``).
    """

    kind: str
    n_channels: int
    n_runs: int
    has_ref: bool
    sensor: str
    signal_periods: int
    radius_m: float | None
    rows: Mapping[str, np.ndarray]
    consts: Mapping[str, Any]
    noise: np.ndarray
    revolutions: np.ndarray
    meta: Mapping[str, Any]
    settings: FinderSettings = DEFAULT_SETTINGS
    max_order: int = 0
    driver_name: str | None = None
    noise_info: Any = None
    data: Any = None
    orders_left_out: tuple[int, ...] = ()


@dataclasses.dataclass(frozen=True)
class Probe:
    """One unit-size effect of a candidate, whose smallest detectable size a verdict that
    does not name it reports (``detection_bounds``, issue 44 F;
    :mod:`encdesign.diagnose.engine._bounds`).

    Attributes:
        values: parameter values of the effect at size 1 (in ``unit``): its linear
            parameters where it acts (the size scales them all), its nonlinear ones at the
            value the bound is stated for (e.g. a frequency, a change point).
        parameter: the size's name in the report (``amplitude_rad``, ``delay_step_s``).
        unit: SI unit of the size.
        where: the channel (head, sensor) it acts on, or ``"all"``.
        at: in words, where its other parameters are held (``"at 123.4 Hz"``).
        worst_of: more probes of the same effect (e.g. other change points): the bound is
            the largest over this probe and these.
        seen: ``seen(lam) -> lam_seen``: the noncentrality the finder's tests see of an
            effect whose noncentrality at the record's noise is ``lam``, where the kind's
            noise estimate takes part of it (a level estimated from few values, which an
            effect below its own step test inflates: the sds run means); ``None``: all of it.
        seen_of: instead of ``seen``, ``seen_of(resid, lam_unit) -> seen``: built by the
            bound from the model's residual of the unit effect on the kept rows (n, C; what the
            kind's noise stage would see of it) and that residual's noncentrality.
        label: in words, what sets this probe apart from the others of its ``worst_of``
            (``"order 2"``, ``"azimuth 45 deg"``): each one's own bound is reported beside the
            worst (``each``), so an effect of a known shape can be read against its own.
        held: nonlinear parameters the finder's fit holds where the effect has ``values``
            (e.g. a drift's onset before the record, whose column the base spans): not
            counted in the bound's ``k``.
        size: the effect's size (in ``unit``) at ``values`` (default 1). Where the size is
            not a linear parameter (an axis tilt's ``beta^2 / 4``), ``values`` hold the
            nonlinear ones where the effect is still linear in its size (a small tilt) and
            ``size`` says how large it is there: the bound is that many times the multiple
            of the effect at ``values`` the finder would reveal.
    """

    values: Mapping[str, Any]
    parameter: str
    unit: str
    where: str = "all"
    at: str = ""
    worst_of: tuple[Probe, ...] = ()
    seen: Callable[[float], float] | None = None
    seen_of: Callable[[np.ndarray, float], Callable[[float], float] | None] | None = None
    size: float = 1.0
    label: str = ""
    held: tuple[str, ...] = ()


ProbeFn = Callable[[Context], list[Probe]]
"""``probes(ctx) -> [Probe, ...]``: the unit-size effects a verdict bounds (when it does not
name the candidate)."""

StartFn = Callable[[Context, np.ndarray, list], list[dict[str, np.ndarray]]]
"""``start(ctx, residual, findings) -> [params, ...]``: starting values for the nonlinear
parameters (one dict per alternative start; linear ones may be left out, they start at 0)."""


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A candidate effect (or a base-model term) the engine can fit.

    Attributes:
        name: catalog name (``docs/effects.md``) or the user's own name.
        fn: the term, ``fn(params, x) -> (n, C)`` (see module doc).
        params: its parameters.
        signature: views it shows in (``spectrum``, ``orders``, ``time``, ``drift``,
            ``line_phase``, ``direction``, ``speed``, ``angle_trend``, ``floor``): the engine
            tries it only when one of those views located something (an empty signature:
            tried whenever the residual fails the goodness-of-fit test).
        kinds: recording kinds it applies to.
        explanation: what it means physically (the report adds the fitted numbers).
        applies: ``applies(ctx) -> None`` or the reason it cannot be tested on this record.
        start: starting values for nonlinear parameters (see :data:`StartFn`).
        plausible: ``plausible(ctx, params) -> None`` or the reason the fitted size is not
            physical (the effect is then refused with that reason).
        derived: ``derived(ctx, params, se) -> dict`` extra reported quantities (e.g. a
            length from an angle), each ``{"value", "se", "unit"}``.
        doubt_overruled: ``True`` (default): ``plausible`` is a doubt about the fitted size
            that the data may overrule (a candidate far ahead of every other is named with
            the doubt and its alternatives, ``FinderSettings.dominant_ratio``); ``False``:
            its ``plausible`` is itself a test the data failed (``vibration``: at one speed
            the line must beat the rotation-locked order), always a refusal.
        valjac: ``valjac(params, x) -> (value (n, C), {name: (n, C, *shape)})``, the value
            and Jacobian written by hand, or ``None`` (default): ``jax.jacfwd`` of ``fn``.
            For a term with many parameters (the base: forward mode carries one tangent per
            parameter through every intermediate) it is several times faster; it must
            agree with ``jax.jacfwd(fn)`` (tested).
        value: ``value(params, x) -> (n, C)``, ``fn`` computed another way, faster, or ``None``
            (default: ``fn``): what the fitter evaluates where it needs no Jacobian (a
            residual, a trial point); it must equal ``fn`` to rounding (tested).
        probes: ``probes(ctx) -> [Probe, ...]`` (:data:`ProbeFn`): the unit-size effects
            whose smallest detectable size a verdict that does not name it reports
            (``detection_bounds``), or ``None`` (default: no bound reported for it).
        orders: the integer orders it is a set of lines at (``signal_shape``: its radial
            orders), or ``()`` (default): named only if its fitted error is not dominated by
            its top order while a larger located structure it leaves continues above it
            (rule ``edge_order``: a piece of an out-of-catalog comb).
        rivals: ``rivals(ctx) -> [Candidate, ...]``, or ``None`` (default: none): located
            structure of this record that no catalog effect makes (an SDS one-run transient
            on one sensor) as terms of its own; the candidate must keep
            ``FinderSettings.located_share_min`` of its gain once each is fitted with it
            (rule ``located_share_min``, :func:`._spill.rival_rule`): a smooth effect with
            many parameters takes a part of a transient, and dominance must not name it.
        time_profile: ``time_profile(fitter, prep, terms, idx, name) -> located_time or
            None``: the kind's own profile of the time parameter ``name`` of ``terms[idx]``
            (a ``global_time``), or ``None`` (default; also where it returns ``None``):
            :func:`._steps.time_param_interval`'s (issue 44 C, session 24: a shift on part
            of a turn profiled with the runs' angle zeros chosen jointly with it).
    """

    name: str
    fn: Callable[[dict, dict], Any]
    params: tuple[Param, ...]
    signature: tuple[str, ...] = ()
    kinds: tuple[str, ...] = ("multihead",)
    explanation: str = ""
    applies: Callable[[Context], str | None] | None = None
    start: StartFn | None = None
    plausible: Callable[[Context, dict], str | None] | None = None
    derived: Callable[[Context, dict, dict], dict] | None = None
    doubt_overruled: bool = True
    valjac: Callable[[dict, dict], Any] | None = None
    value: Callable[[dict, dict], Any] | None = None
    probes: ProbeFn | None = None
    orders: tuple[int, ...] = ()
    rivals: Callable[[Context], Sequence[Candidate]] | None = None
    time_profile: Callable[..., dict | None] | None = None

    def __post_init__(self) -> None:
        names = [p.name for p in self.params]
        if len(set(names)) != len(names):
            raise ValueError(f"candidate {self.name!r}: parameter names repeat: {names}")
        if not callable(self.fn):
            raise TypeError(f"candidate {self.name!r}: fn must be callable")

    def shapes(self, n_channels: int, n_runs: int) -> dict[str, tuple[int, ...]]:
        """Parameter name -> array shape for a recording of that size."""
        return {p.name: p.resolved_shape(n_channels, n_runs) for p in self.params}

    def size(self, n_channels: int, n_runs: int) -> int:
        """Number of scalar parameters."""
        return int(sum(np.prod(s, dtype=int) for s in self.shapes(n_channels, n_runs).values()))
