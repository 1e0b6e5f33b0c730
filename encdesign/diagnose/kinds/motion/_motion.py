"""Motion kind for the engine: shaft angle against time (``docs/effects.md``, "Shaft motion").

Base model per steady segment's run ``r``: a polynomial in time (start angle, constant speed
and a slow drift of the speed loop; a cubic, of higher degree over many revolutions,
:func:`drift_degree`) plus the motor's design ripple (with ``commutation_states``:
position harmonics at multiples of ``commutation_states * pole_pairs`` per revolution).
A speed ripple of relative amplitude ``q`` at order ``m`` moves the angle by ``q / m`` rad,
so every candidate is a set of Fourier orders of the angle (``p`` pole pairs, ``s`` slots):

* ``cogging``: multiples of ``lcm(2p, s)``;
* ``magnet_asymmetry``: multiples of ``p``;
* ``coil_mismatch``: ``1 .. p`` and multiples of ``s``;
* ``speed_control_loop``: ripple fixed in Hz rather than in order: not modelled (listed as
  not testable).

An order shared by two candidates is one column of the data: it is credited to the
candidate whose lowest harmonic it is (``assigned_orders``: ``lcm(2p, s)`` is cogging's
fundamental but ``lcm / p``-th multiple of ``p`` and ``lcm / s``-th multiple of ``s``; ties go
in catalog order) and the effect reports the other candidates that order also belongs to
(``derived.orders_shared_with``): the record cannot tell them apart there. Each candidate's
orders reach its fundamental whenever the sampling resolves it (``nyquist_order``), even
when the base model's parameter budget sets a lower ``max_order`` (a cogging fundamental at
order 84 costs two parameters).
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar, final

import jax.numpy as jnp
import numpy as np

from ...._errors import input_error
from ....io._recording import Recording
from ...engine._candidates import Candidate, Context, Param, Probe
from ...engine._kind import AbstractKind
from ...engine._prepare import prepare as engine_prepare
from ...engine._protocol import KindData, Prepared, drive_channel
from ...engine._settings import DEFAULT_SETTINGS, FinderSettings

EXPLANATIONS = {
    "cogging": (
        "Magnet-to-slot attraction (cogging torque) was left out: it makes the speed ripple "
        "at multiples of lcm(2*pole_pairs, slots) per revolution, strongest at low speed."
    ),
    "magnet_asymmetry": (
        "Unequal magnets or pole spacing were left out: the torque, and so the speed, "
        "ripples at multiples of the pole-pair count per revolution."
    ),
    "coil_mismatch": (
        "Unequal stator coils were left out: they add low-order speed harmonics (orders 1 .. "
        "pole_pairs) and harmonics at multiples of the slot count."
    ),
}


def motion_angle(rec: Recording) -> np.ndarray:
    """Shaft angle in rad (``theta``, or ``counts`` with ``counts_per_rev``)."""
    if "theta" in rec.columns:
        return np.asarray(rec.columns["theta"], float)
    return np.asarray(rec.columns["counts"], float) / rec.encoder["counts_per_rev"] * 2 * np.pi


def candidate_orders(pole_pairs: int, slots: int | None, max_order: int) -> dict[str, list[int]]:
    """Orders per revolution of each catalog candidate for a motor (see module doc)."""
    p = pole_pairs
    out: dict[str, list[int]] = {}
    if slots:
        lcm = 2 * p * slots // math.gcd(2 * p, slots)
        out["cogging"] = list(range(lcm, max_order + 1, lcm))
    out["magnet_asymmetry"] = list(range(p, max_order + 1, p))
    coil = set(range(1, p + 1))
    if slots:
        coil |= set(range(slots, max_order + 1, slots))
    out["coil_mismatch"] = sorted(m for m in coil if m <= max_order)
    return {k: v for k, v in out.items() if v}


def _harmonic_index(name: str, m: int, p: int, s: int | None) -> float:
    """Which harmonic of ``name``'s family order ``m`` is (1: its fundamental)."""
    if name == "cogging":
        return m / (2 * p * s // math.gcd(2 * p, s))
    if name == "magnet_asymmetry":
        return m / p
    return 1.0 if m <= p else m / s  # coil_mismatch: the low orders 1..p, then slot multiples


def assigned_orders(
    pole_pairs: int, slots: int | None, max_order: int
) -> tuple[dict[str, list[int]], dict[str, dict[int, list[str]]]]:
    """The catalog's orders (:func:`candidate_orders`) with every shared order credited to
    one candidate only, the one whose lowest harmonic it is (ties in catalog order).

    Returns ``(orders, shared)``: ``orders[name]`` the orders it fits, ``shared[name][m]``
    the other candidates order ``m`` also belongs to (confounded there)."""
    cat = candidate_orders(pole_pairs, slots, max_order)
    names = list(cat)
    owners: dict[int, list[str]] = {}
    for n in names:
        for m in cat[n]:
            owners.setdefault(m, []).append(n)
    orders: dict[str, list[int]] = {n: [] for n in names}
    shared: dict[str, dict[int, list[str]]] = {n: {} for n in names}
    for m, own in sorted(owners.items()):
        best = min(own, key=lambda n: (_harmonic_index(n, m, pole_pairs, slots), names.index(n)))
        orders[best].append(m)
        if len(own) > 1:
            shared[best][m] = [n for n in own if n != best]
    return {n: v for n, v in orders.items() if v}, shared


def _motor(rec: Recording) -> dict:
    where = str(rec.path) if rec.path is not None else "recording"
    motor = rec.meta.get("motor", {})
    if "pole_pairs" not in motor:
        raise input_error(f"{where}: [motor]", "missing pole_pairs", "the motor's pole pairs")
    return motor


def motion_data(rec: Recording) -> KindData:
    """Observations of a motion recording (the shaft angle itself)."""
    _motor(rec)
    theta = motion_angle(rec)
    return KindData(
        **drive_channel(
            theta[:, None],
            theta,
            np.asarray(rec.columns["t"], float),
            np.asarray(rec.runs),
            unit="rad",
            channel_name="theta",
            sensor="motion",
            where=str(rec.path) if rec.path is not None else "recording",
        )
    )


@functools.lru_cache(maxsize=64)
def _fourier(
    name: str,
    orders: tuple[int, ...],
    explanation: str,
    signature=("orders", "spectrum"),
    shared: tuple[tuple[int, tuple[str, ...]], ...] = (),
):
    """Fourier terms of the angle at ``orders`` (one object per order set: one compile);
    ``shared``: ``(order, other candidates it belongs to)``, reported with the effect."""
    orders = list(orders)
    m = jnp.asarray(orders, dtype=float)

    def fn(p, x):
        arg = x["theta"][:, None] * m[None, :]
        return (jnp.cos(arg) @ p["cos_rad"] + jnp.sin(arg) @ p["sin_rad"])[:, None]

    def derived(ctx, v, se):
        amp = np.hypot(v["cos_rad"], v["sin_rad"])
        top = np.argsort(-amp)[:8]
        out = {
            "orders": {"value": [int(o) for o in orders], "se": None, "unit": "1"},
            "angle_amplitude_rad": {
                "value": {str(orders[i]): float(amp[i]) for i in top},
                "se": None,
                "unit": "rad",
            },
            "speed_ripple_relative": {
                "value": {str(orders[i]): float(orders[i] * amp[i]) for i in top},
                "se": None,
                "unit": "1",
            },
        }
        if shared:
            # the same column belongs to other candidates too: confounded at those orders
            out["orders_shared_with"] = {
                "value": {str(m): list(o) for m, o in shared},
                "se": None,
                "unit": "1",
                "note": "these orders are also the other candidates' (the same Fourier "
                "column): credited to this one, whose lowest harmonic they are; the record "
                "cannot tell them apart there",
            }
        return out

    def probes(ctx):
        # at its lowest order: the fundamental its family is named by (the bound of each
        # higher harmonic alone is about the same: one column pair each)
        c = np.zeros(len(orders))
        c[0] = 1.0
        vals = {"cos_rad": c, "sin_rad": np.zeros(len(orders))}
        return [Probe(vals, "amplitude_rad", "rad", where="theta", at=f"order {orders[0]}")]

    return Candidate(
        name,
        fn,
        (Param("cos_rad", "rad", (len(orders),)), Param("sin_rad", "rad", (len(orders),))),
        signature=signature,
        kinds=("motion",),
        explanation=explanation,
        derived=derived,
        probes=probes,
    )


@functools.lru_cache(maxsize=16)
def _poly_candidate(R: int, D: int) -> Candidate:
    """Per run a polynomial of degree ``D`` in normalised time (Legendre basis: start angle,
    speed and the speed loop's slow drift)."""

    def fn(p, x):
        tn = x["t_norm"]
        cols = [jnp.ones_like(tn), tn]
        for k in range(2, D + 1):  # Bonnet's recursion
            cols.append(((2 * k - 1) * tn * cols[-1] - (k - 1) * cols[-2]) / k)
        X = jnp.stack(cols[: D + 1], 1)  # (n, D + 1)
        coef = x["run_onehot"] @ p["poly_rad"]  # (n, D + 1)
        return jnp.sum(X * coef, 1)[:, None]

    return Candidate(
        "base",
        fn,
        (
            Param(
                "poly_rad",
                "rad",
                (R, D + 1),
                description=f"per run: angle, speed, drift (Legendre degree {D})",
            ),
        ),
        kinds=("motion",),
        explanation=f"base model: constant speed and a slow speed drift per run (degree {D})",
    )


def drift_degree(revolutions: float, settings: FinderSettings) -> int:
    """Degree of the drift polynomial of a run of ``revolutions`` turns
    (``settings.drift_degree_min`` to ``drift_degree_max``, one more per
    ``drift_turns_per_degree`` turns beyond ``drift_growth_turns``)."""
    s = settings
    grown = max(0.0, revolutions - s.drift_growth_turns) // s.drift_turns_per_degree
    return int(min(s.drift_degree_max, s.drift_degree_min + grown))


def nyquist_order(kept_per_run: np.ndarray, revolutions: np.ndarray) -> int:
    """Below half the kept samples per revolution of the sparsest-sampled run (at least 1):
    the base's limit before its parameter budget, and how far the candidates' fundamentals
    reach."""
    spr = [kept_per_run[r] / revolutions[r] for r in range(len(revolutions)) if revolutions[r] > 0]
    return int(max(1, int(math.floor(min(spr) / 2.0)) - 1 if spr else 1))


def motion_limit(prep: Prepared) -> int:
    """Highest order the record resolves (below half the samples per revolution)."""
    kept = np.array([((prep.run == r) & prep.keep).sum() for r in range(prep.ctx.n_runs)])
    nyq = nyquist_order(kept, prep.ctx.revolutions)
    D = drift_degree(float(np.min(prep.ctx.revolutions)), prep.settings)
    budget = int(
        (prep.settings.max_param_fraction * prep.n_values - (D + 1) * prep.ctx.n_runs) // 2
    )
    return int(max(1, min(nyq, budget)))


def motion_base(prep: Prepared, M: int):
    """Cubic per run plus the design ripple orders."""
    t = prep.rows["t"]
    tn = np.zeros_like(t)
    for r in range(prep.ctx.n_runs):
        m = prep.run == r
        k = m & prep.keep
        lo, hi = (t[k].min(), t[k].max()) if k.any() else (t[m].min(), t[m].max())
        tn[m] = (t[m] - 0.5 * (lo + hi)) / max(0.5 * (hi - lo), 1e-12)
    prep.rows["t_norm"] = tn
    motor = prep.ctx.meta.get("motor", {})
    p = int(motor["pole_pairs"])
    D = drift_degree(float(np.min(prep.ctx.revolutions)), prep.settings)
    terms = [(_poly_candidate(prep.ctx.n_runs, D), {})]
    design = []
    if "commutation_states" in motor:
        step = int(motor["commutation_states"]) * p
        design = list(range(step, M + 1, step))
    if design:
        terms.append((_fourier("design_ripple", tuple(design), "design ripple", ()), {}))
    info = {
        "design_ripple_orders": design,
        "pole_pairs": p,
        "stator_slots": motor.get("stator_slots"),
        "drift_degree": D,
        "unidentifiable": [],
    }
    return terms, info


def motion_candidates(ctx: Context) -> tuple[Candidate, ...]:
    """cogging, magnet_asymmetry, coil_mismatch at this motor's orders."""
    motor = ctx.meta.get("motor", {})
    p, s = int(motor["pole_pairs"]), motor.get("stator_slots")
    M = int(ctx.max_order)
    kept = np.asarray(ctx.rows["run_onehot"]).sum(0)  # kept rows per run
    nyq = nyquist_order(kept, ctx.revolutions)
    design = set()
    if "commutation_states" in motor:
        step = int(motor["commutation_states"]) * p
        design = set(range(step, nyq + 1, step))
    out = []
    cat, shared = assigned_orders(p, s, nyq)
    for name, orders in cat.items():
        # up to max_order, and at least the candidate's lowest order the sampling resolves
        orders = [m for m in orders if m not in design]
        orders = [m for i, m in enumerate(orders) if m <= M or i == 0]
        if orders:
            sh = tuple((m, tuple(shared[name][m])) for m in orders if m in shared[name])
            out.append(_fourier(name, tuple(orders), EXPLANATIONS[name], shared=sh))
    out.append(
        Candidate(
            "speed_control_loop",
            lambda p_, x: jnp.zeros_like(x["reading"]),
            (),
            signature=("spectrum",),
            kinds=("motion",),
            applies=lambda ctx: (
                "ripple shaped by a speed loop is not modelled for motion "
                "recordings; telling ripple fixed in Hz from ripple fixed in order needs runs at "
                "different speeds"
            ),
        )
    )
    return tuple(out)


@final
class MotionKind(AbstractKind):
    """``motion``: a motor's shaft angle in time (speed ripple, cogging, ...)."""

    name: ClassVar[str] = "motion"
    default_max_order: ClassVar[int] = 200
    noise_replaces: ClassVar[bool] = False
    grows_orders: ClassVar[bool] = False
    reading_lattice: ClassVar[bool] = True

    def data(self, rec, settings=DEFAULT_SETTINGS):
        return motion_data(rec)

    def views(self, prep):
        return ("orders", "spectrum", "band", "time")

    def plots(self, d, folder):
        return []

    def prepare(self, kd, meta, settings):
        return engine_prepare(kd, meta, settings)

    def base(self, prep, max_order):
        return motion_base(prep, max_order)

    def candidates(self, ctx):
        return motion_candidates(ctx)

    def max_order_limit(self, prep):
        return motion_limit(prep)

    def noise(self, prep, base_resid):
        return None

    def refine(self, terms, prep):
        return None

    def align(self, terms, prep):
        return None

    def summary(self, prep, base_params):
        return {}

    def finish(self, prep, doc, settings):
        return doc

    def report_lines(self, doc):
        return ""


MOTION = MotionKind()
