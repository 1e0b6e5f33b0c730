"""Concealed benches for the engine's blind benchmark (``studies/conceal_benchmark.py``).

Each bench is drawn from a plan (:func:`draw_plan`) and simulated here, independently of the
engine's terms (the effects are written out from their physics, not with the finder's
functions, so a wrong term in the finder cannot agree with itself):

* ``multihead``: 2 to 6 heads at random azimuths (one reference head off the symmetry),
  optical radius 10-100 mm, 1,000-100,000 lines, 1-3 runs of less than one turn to 50 turns,
  0.5 urad noise, base errors (eccentricity of a few um, tilt, grating errors of orders 2-6,
  head placements), with or without ``theta_ref``;
* ``sensor``: one sensor against a reference (``theta_ref``), magnetic / resolver /
  capacitive / optical, its error function of a few orders, one or two directions;
* ``motion``: a 7-pole-pair, 12-slot motor turning at constant speed (``theta`` against t);
* ``quadrature``: the two signals of one head (:func:`simulate_quadrature`): sorted by phase
  or in time order (with a dwell or a reversal), ellipse errors, optionally on DC levels;
  ``signal_shape`` (1 or, compound, 3 signal harmonics), out of catalog: a radial order above
  12, an amplitude step, clipping.

Nuisances (any bench): per-run zeros of every head and of ``theta_ref`` (whole turns or any
amount), a non-steady segment at the start of a run (start-up ramp or a return move, with
an oscillation while it lasts), single-sample glitches. Effects: 0-3 catalog effects at
0.5x or 1x the per-sample noise (amplitude of the error they add), or one out-of-catalog
structure (an integer order on one head, a step on one head, a chirp on one head).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..io._recording import Recording

MULTIHEAD_EFFECTS = (
    "beam_tilt_axial",
    "bearing_wobble",
    "vibration",
    "thermal_drift",
    "interpolation_error",
    "eccentricity_shift",
)
SENSOR_EFFECTS = (
    "direction_hysteresis",
    "reading_delay",
    "quantization",
    "scale_error",
    "interpolation_error",
    "vibration",
)
MOTION_EFFECTS = ("cogging", "magnet_asymmetry", "coil_mismatch")
OUT_OF_CATALOG = ("order_one_head", "step_one_head", "chirp_one_head")


def draw_plan(rng: np.random.Generator, kind: str, case: str) -> dict[str, Any]:
    """A bench plan: ``case`` is ``clean``, ``single``, ``weak`` (0.5x noise), ``compound``
    or ``out_of_catalog``."""
    if kind == "quadrature":
        return draw_quadrature_plan(rng, case)
    plan: dict[str, Any] = {"kind": kind, "case": case}
    plan["per_run_zeros"] = bool(rng.random() < 0.7)
    plan["transient"] = bool(rng.random() < 0.5)
    plan["glitches"] = int(rng.integers(0, 3)) if rng.random() < 0.4 else 0
    if kind == "multihead":
        plan["n_heads"] = int(rng.integers(2, 7))
        plan["radius_m"] = float(rng.uniform(0.01, 0.1))
        plan["lines"] = int(rng.choice([1000, 2048, 5000, 10000, 36000, 100000]))
        plan["theta_ref"] = bool(rng.random() < 0.5) or plan["n_heads"] == 2
        plan["n_runs"] = int(rng.integers(1, 4))
        plan["turns"] = float(np.exp(rng.uniform(np.log(0.6), np.log(50.0))))
        pool = MULTIHEAD_EFFECTS
    elif kind == "sensor":
        plan["sensor"] = str(rng.choice(["magnetic", "resolver", "capacitive", "optical"]))
        plan["periods"] = {
            "magnetic": int(rng.choice([1, 7, 21])),
            "resolver": int(rng.choice([1, 2, 4])),
            "capacitive": int(rng.choice([8, 16])),
            "optical": 2048,
        }[plan["sensor"]]
        plan["n_runs"] = int(rng.integers(1, 3))
        plan["both_directions"] = bool(rng.random() < 0.6)
        plan["turns"] = float(rng.choice([0.8, 1.0, 2.0, 5.0]))
        pool = SENSOR_EFFECTS
    else:
        plan["n_runs"] = 1
        plan["turns"] = float(rng.choice([1.0, 2.0, 4.0]))
        pool = MOTION_EFFECTS
    if case == "clean":
        plan["effects"] = []
    elif case in ("single", "weak"):
        plan["effects"] = [str(rng.choice(pool))]
    elif case == "compound":
        k = int(rng.integers(2, 4))
        plan["effects"] = [str(x) for x in rng.choice(pool, size=min(k, len(pool)), replace=False)]
    else:
        # a sensor's integer order is part of its own error function (the base model), so
        # out of the catalog there is a step or a chirp
        pool_ooc = OUT_OF_CATALOG if kind == "multihead" else OUT_OF_CATALOG[1:]
        plan["effects"] = [str(rng.choice(pool_ooc))] if kind != "motion" else []
        if kind == "motion":
            plan["effects"] = ["order_one_head"]
    plan["amplitude"] = 0.5 if case == "weak" else 1.0
    return fix_plan(plan, rng)


def fix_plan(plan: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
    """Settings without which an effect is not identifiable (the engine then reports it as
    not testable or confounded, which the benchmark does not score as a name)."""
    if "reading_delay" in plan["effects"]:
        # one direction: a delay is a constant per run; one |speed| in both directions: it is
        # a direction offset (h = -2 |omega| tau). Two speeds (two runs) separate them
        plan["both_directions"] = True
        if plan["kind"] == "sensor":
            plan["n_runs"] = max(plan["n_runs"], 2)
    if "scale_error" in plan["effects"]:
        # over part of a turn it is an order-1 error; in one direction at one speed the
        # angle is linear in time and s * theta is a drift in time: turn back
        plan["turns"] = max(plan["turns"], 2.0)
        plan["both_directions"] = True
    if plan["kind"] == "sensor" and "interpolation_error" in plan["effects"]:
        plan["periods"] = int(rng.choice([16, 21, 2048]))  # above the base model's orders
    if "direction_hysteresis" in plan["effects"]:
        plan["both_directions"] = True
    if plan["kind"] == "sensor" and "step_one_head" in plan["effects"]:
        # over less than a turn in one direction a step in time is a step of the angle: part
        # of the sensor's own error function (the base model), like an integer order
        if not plan.get("both_directions"):
            plan["turns"] = max(plan["turns"], 2.0)
    if "vibration" in plan["effects"]:
        # at one speed a line fixed in Hz is a rotation-locked error at a shaft order unless
        # the span resolves its order from an integer (1 / turns): over a turn or two it never
        # does (the engine then reports that it cannot tell them)
        plan["turns"] = max(plan["turns"], 5.0)
    if "bearing_wobble" in plan["effects"]:
        plan["turns"] = max(plan["turns"], 10.0)
    if "thermal_drift" in plan["effects"] and plan["kind"] == "multihead":
        plan["turns"] = max(plan["turns"], 2.0)
    return plan


def _shaft(rng, n: int, turns: float, both: bool, transient: bool, rate_hz: float):
    """Shaft angle (rad) and time (s) of one run; ``transient``: a non-steady start
    (start-up ramp from rest, or a fast return move) before the steady part. Returns
    (t, theta, steady mask)."""
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt * (1.0 + 0.02 * rng.uniform(-1, 1))
    span = turns * 2 * np.pi
    kind_tr = ("startup" if rng.random() < 0.5 else "return") if transient else None
    n_tr = int((0.12 if kind_tr == "startup" else 0.05) * n) if transient else 0
    steady = np.ones(n, bool)
    th = np.empty(n)
    m = n - n_tr
    if both:
        half = m // 2
        w = span / (half * dt)
        up = np.arange(half) * dt * w
        down = up[-1] - np.arange(m - half) * dt * w
        prof = np.concatenate([up, down])
    else:
        w = span / (m * dt)
        prof = np.arange(m) * dt * w
    if n_tr:
        if kind_tr == "startup":  # accelerate from rest
            s = np.arange(n_tr) / n_tr
            pre = np.cumsum(w * s) * dt
            pre = pre - pre[-1] - w * dt
        else:  # a return move: backwards at 3x the steady speed, into the start position
            pre = 3 * w * dt * (n_tr - np.arange(n_tr))
        th[:n_tr] = pre
        th[n_tr:] = prof
        steady[:n_tr] = False
    else:
        th[:] = prof
    th += rng.uniform(0, 2 * np.pi)
    return t, th, steady


def simulate_plan(
    rng: np.random.Generator, plan: dict[str, Any]
) -> tuple[Recording, dict[str, Any]]:
    """Simulate a bench from a plan; returns the recording (in memory) and the truth."""
    kind = plan["kind"]
    if kind == "motion":
        return _simulate_motion(rng, plan)
    if kind == "quadrature":
        return simulate_quadrature(rng, plan)
    sensor = kind == "sensor"
    H = 1 if sensor else plan["n_heads"]
    R = plan["n_runs"]
    noise = 0.5e-6 if not sensor else float(rng.uniform(2e-5, 2e-4))
    A = plan["amplitude"] * noise
    rate = 200.0
    n_run = int(max(300, min(1400, 3000 // R)))
    if sensor:
        alpha = np.zeros(1)
    else:
        alpha = np.sort(rng.uniform(0, 2 * np.pi, H))
        alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.3, 2 * np.pi - 0.3, H - 1))])
    Rm = plan.get("radius_m", 0.0254)
    L = plan.get("lines", plan.get("periods", 0))
    speeds = [1.0, 1.6, 0.7][:R]
    runs = []
    for r in range(R):
        t, th, steady = _shaft(
            rng,
            n_run,
            plan["turns"] * speeds[r],
            plan.get("both_directions", False),
            plan["transient"] and r == 0,
            rate * speeds[r] if sensor else rate,
        )
        runs.append((t, th, steady))
    t = np.concatenate([x[0] for x in runs])
    theta = np.concatenate([x[1] for x in runs])
    steady = np.concatenate([x[2] for x in runs])
    run = np.repeat(np.arange(R), n_run)
    n = t.size
    tau = np.concatenate([x[0] + r * (x[0][-1] + 1.0) for r, x in enumerate(runs)])
    temp = 21.0 + 0.8 * np.sin(2 * np.pi * tau / (tau[-1] * 1.7) + rng.uniform(0, 6.3))
    # base errors: one disk error function seen through every head
    err = np.zeros((n, H))
    place = np.concatenate([[0.0], rng.normal(0, 1e-3, H - 1)])
    big = 30.0 * noise if not sensor else 20.0 * noise
    orders = range(1, 7)
    amps = {m: big / m * rng.uniform(0.3, 1.0) for m in orders}
    phs = {m: rng.uniform(0, 2 * np.pi) for m in orders}
    for k in range(H):
        for m in orders:
            err[:, k] += amps[m] * np.sin(m * (theta - alpha[k] - place[k]) + phs[m])
    extra = np.zeros((n, H))
    truth: dict[str, Any] = {"plan": plan, "effects": list(plan["effects"]), "where": None}
    omega = np.gradient(theta, t)
    direction = np.sign(np.where(np.abs(omega) > 0, omega, 1.0))
    quant = None
    for eff in plan["effects"]:
        if eff == "beam_tilt_axial":
            m = int(rng.integers(1, 4))
            beta = rng.uniform(0.3, 1.0, H) * rng.choice([-1, 1], H)
            if not plan["theta_ref"]:
                beta = beta - beta.mean()
            beta = beta / np.max(np.abs(beta))
            ph = rng.uniform(0, 2 * np.pi)
            extra += A * 1.5 * np.sin(m * theta + ph)[:, None] * beta[None, :]
        elif eff == "bearing_wobble":
            nu = rng.uniform(0.35, 0.45)
            ph = rng.uniform(0, 2 * np.pi, R)[run]
            extra += A * 1.5 * np.sin(nu * theta[:, None] + ph[:, None] - alpha[None, :])
        elif eff == "vibration":
            f = rng.uniform(0.2, 0.8) * rate / 2 * (1.0 if not sensor else 0.5)
            ph = rng.uniform(0, 2 * np.pi, (R, H))[run]
            amp = A * rng.uniform(0.7, 1.0, H)
            extra += amp[None, :] * np.sin(2 * np.pi * f * t[:, None] + ph)
        elif eff == "thermal_drift":
            kap = rng.uniform(-1.0, 1.0, H)
            kap[int(rng.integers(H))] = rng.choice([-1, 1])
            if not plan.get("theta_ref", True):
                kap = kap - kap.mean()
            kap = kap / np.max(np.abs(kap))
            extra += A * 1.5 * (temp - temp.mean())[:, None] / np.std(temp) * kap[None, :] / 1.5
        elif eff == "interpolation_error":
            psi = L * (theta[:, None] + err)
            o = A * rng.uniform(0.6, 1.0, (2, H)) * rng.choice([-1, 1], (2, H))
            # signal offset gives order 1 of the period, an amplitude error order 2
            extra += (o[0] * np.cos(psi) + o[1] * np.sin(2 * psi)) * 1.2
        elif eff == "eccentricity_shift":
            ts = tau[0] + (tau[-1] - tau[0]) * rng.uniform(0.3, 0.7)
            ph = rng.uniform(0, 2 * np.pi)
            extra += (tau >= ts)[:, None] * A * 1.5 * np.sin(theta[:, None] - alpha[None, :] + ph)
            truth["shift_time_s"] = float(ts)
            # on the recording's own clock: the first row after the shift and its run
            i = int(np.searchsorted(tau, ts))
            truth["shift_at"] = {"time_s": float(t[i]), "run": int(run[i])}
        elif eff == "direction_hysteresis":
            extra += 0.5 * A * 2 * direction[:, None]
        elif eff == "reading_delay":
            tau_s = A * 2 / max(np.max(np.abs(omega)), 1e-9)
            extra += -(omega * tau_s)[:, None]
        elif eff == "quantization":
            quant = 2 * np.pi / 2 ** int(rng.integers(12, 15))
            quant = max(quant, 4 * noise)
        elif eff == "scale_error":
            s = A * 2 / max(np.ptp(theta), 1e-9)
            extra += s * (theta - theta.mean())[:, None]
        elif eff == "order_one_head":
            k = int(rng.integers(H))
            m = int(rng.integers(5, 9))
            extra[:, k] += 2.5 * A * np.sin(m * theta + rng.uniform(0, 2 * np.pi))
            truth["where"] = {"heads": [k], "orders": [m]}
        elif eff == "step_one_head":
            k = int(rng.integers(H))
            i = int(np.flatnonzero(steady)[int(rng.uniform(0.3, 0.7) * steady.sum())])
            extra[i:, k] += 4 * A * rng.choice([-1, 1]) * (run[i:] == run[i])
            truth["where"] = {"heads": [k], "times_s": [float(t[i])], "runs": [int(run[i])]}
        elif eff == "chirp_one_head":
            k = int(rng.integers(H))
            dur = t[run == 0][-1]
            f0, f1 = 0.15 * rate, 0.35 * rate
            tt = t
            extra[:, k] += 2.5 * A * np.sin(2 * np.pi * (f0 * tt + 0.5 * (f1 - f0) / dur * tt**2))
            truth["where"] = {"heads": [k], "frequencies_hz": [f0, f1]}
    # the non-steady start carries a settling oscillation (must be excluded, not fitted)
    if plan["transient"]:
        bad = ~steady
        extra[bad] += 20 * noise * np.sin(2 * np.pi * 7.0 * t[bad])[:, None]
    readings = theta[:, None] + err + extra + rng.normal(0, noise, (n, H))
    if quant is not None:
        readings = np.round(readings / quant) * quant
        truth["lsb_rad"] = float(quant)
    ref = theta.copy()
    if plan["per_run_zeros"]:
        for r in range(R):
            m = run == r
            readings[m] += rng.integers(-3, 4, H) * 2 * np.pi + rng.uniform(-np.pi, np.pi, H)
            ref[m] += rng.integers(-2, 3) * 2 * np.pi + rng.uniform(-np.pi, np.pi)
    else:
        readings += rng.uniform(-1, 1, H)
    glitch_rows = []
    for _ in range(plan["glitches"]):
        i = int(np.flatnonzero(steady)[int(rng.integers(5, steady.sum() - 5))])
        k = int(rng.integers(H))
        readings[i, k] += rng.choice([-1, 1]) * 60 * noise
        glitch_rows.append(i)
    truth["glitch_rows"] = glitch_rows
    truth["transient_rows"] = int((~steady).sum())
    cols: dict[str, np.ndarray] = {"t": t, "run": run}
    use_ref = sensor or plan["theta_ref"]
    if use_ref:
        cols["theta_ref"] = ref
    for k in range(H):
        cols[f"h{k}"] = readings[:, k]
    if "thermal_drift" in plan["effects"] or rng.random() < 0.5:
        cols["temp_c"] = temp
    enc: dict[str, Any] = {"head_angles_deg": [float(np.degrees(a)) for a in alpha]}
    if not sensor:
        enc["optical_radius_m"] = Rm
        enc["grating_lines"] = int(L)
    else:
        enc["sensor"] = plan["sensor"]
        enc["signal_periods_per_rev"] = int(L)
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    truth["noise"] = noise
    return Recording("multihead", meta, cols), truth


def _simulate_motion(rng, plan):
    p, s = 7, 12
    n = 2000
    rate = 500.0
    t, th, steady = _shaft(rng, n, plan["turns"], False, plan["transient"], rate)
    noise = 2e-4
    A = plan["amplitude"] * noise
    orders = {"cogging": [84], "magnet_asymmetry": [7, 14], "coil_mismatch": [1, 3, 12]}
    extra = np.zeros(n)
    truth: dict[str, Any] = {"plan": plan, "effects": list(plan["effects"]), "where": None}
    for eff in plan["effects"]:
        if eff in orders:
            for m in orders[eff]:
                extra += 3 * A * np.sin(m * th + rng.uniform(0, 2 * np.pi))
        elif eff == "order_one_head":
            m = int(rng.choice([11, 43, 53]))  # not a multiple of 7 or 12, above 7
            extra += 4 * A * np.sin(m * th + rng.uniform(0, 2 * np.pi))
            truth["where"] = {"heads": [0], "orders": [m]}
    if plan["transient"]:
        extra[~steady] += 20 * noise * np.sin(2 * np.pi * 5.0 * t[~steady])
    theta = th + extra + rng.normal(0, noise, n)
    truth["glitch_rows"] = []
    for _ in range(plan["glitches"]):
        i = int(np.flatnonzero(steady)[int(rng.integers(5, steady.sum() - 5))])
        theta[i] += rng.choice([-1, 1]) * 60 * noise
        truth["glitch_rows"].append(i)
    truth["transient_rows"] = int((~steady).sum())
    meta = {
        "format": "encdesign-recording/1",
        "kind": "motion",
        "motor": {"pole_pairs": p, "stator_slots": s},
    }
    truth["noise"] = noise
    return Recording("motion", meta, {"t": t, "theta": theta}), truth


# ----------------------------------------------------------------------------- quadrature

QUADRATURE_EFFECTS = ("signal_shape",)
"""The quadrature catalog effects the bench conceals (``vibration`` is not testable from the
two signals alone: the finder lists it as such)."""
QUADRATURE_OUT_OF_CATALOG = ("radial_order", "amplitude_step", "clipping")


def draw_quadrature_plan(rng: np.random.Generator, case: str) -> dict[str, Any]:
    """A quadrature bench plan (``case`` as in :func:`draw_plan`): a capture sorted by phase
    (no ``t``) or in time order (aliased or well sampled, with a dwell or a reversal), an
    ellipse with offsets (optionally on large DC levels, as raw detector signals), amplitude
    mismatch and phase error, 1,500-6,000 samples."""
    plan: dict[str, Any] = {"kind": "quadrature", "case": case}
    plan["timed"] = bool(rng.random() < 0.6)
    plan["transient"] = bool(plan["timed"] and rng.random() < 0.5)
    plan["glitches"] = int(rng.integers(1, 3)) if rng.random() < 0.3 else 0
    plan["n"] = int(rng.integers(1500, 6001))
    plan["scale"] = float(10 ** rng.uniform(-1, 4))
    plan["dc_levels"] = bool(rng.random() < 0.3)
    plan["noise_rel"] = float(10 ** rng.uniform(-4, -2.5))
    plan["samples_per_period"] = float(rng.choice([5.3, 13.7, 40.0, 250.0]))
    if case == "clean":
        plan["effects"] = []
    elif case in ("single", "weak", "compound"):
        plan["effects"] = ["signal_shape"]
    else:
        ooc = [e for e in QUADRATURE_OUT_OF_CATALOG if plan["timed"] or e != "amplitude_step"]
        plan["effects"] = [str(rng.choice(ooc))]
    # compound: several harmonics at once (the catalog's only testable quadrature effect)
    plan["harmonics"] = (
        [int(h) for h in rng.choice([2, 3, 4, 5, 7], size=3, replace=False)]
        if case == "compound"
        else [int(rng.choice([2, 3, 5, 7]))]
    )
    plan["amplitude"] = 0.5 if case == "weak" else 1.0
    return plan


def simulate_quadrature(
    rng: np.random.Generator, plan: dict[str, Any]
) -> tuple[Recording, dict[str, Any]]:
    """Simulate a quadrature bench (seed 002 eq. 1: ``sa = p + a F(phi)``,
    ``sb = q + b F(phi + alpha - pi/2)`` with one shape ``F`` for both channels); the effect
    size is the RMS of the radial error it adds, at ``amplitude`` x the per-sample noise."""
    n = plan["n"]
    s = plan["scale"]
    noise = plan["noise_rel"]
    truth: dict[str, Any] = {"plan": plan, "effects": list(plan["effects"]), "where": None}
    cols: dict[str, np.ndarray] = {}
    steady = np.ones(n, bool)
    if plan["timed"]:
        f_sig = 40.0  # signal periods per s
        rate = f_sig * plan["samples_per_period"]
        t = np.arange(n) / rate * (1 + 0.001 * rng.standard_normal(n).cumsum() / np.sqrt(n))
        t = np.sort(t)
        u = t * f_sig
        if plan["transient"]:
            a0, a1 = int(0.3 * n), int(0.38 * n)
            if rng.random() < 0.5:  # a dwell: the scale stops
                u = np.where(t < t[a0], u, np.where(t < t[a1], u[a0], u - (u[a1] - u[a0])))
            else:  # a reversal and back
                back = np.clip((t - t[a0]) / (t[a1] - t[a0]), 0, 1)
                u = u - 2 * np.minimum(back, 1 - back) * (u[a1] - u[a0])
            steady[a0:a1] = False
        phi = 2 * np.pi * u + rng.uniform(0, 2 * np.pi)
        cols["t"] = t
    else:
        phi = rng.uniform(0, 2 * np.pi, n)
    p = rng.uniform(-0.05, 0.05) + (rng.uniform(1.2, 3.0) if plan["dc_levels"] else 0.0)
    q = rng.uniform(-0.05, 0.05) + (rng.uniform(1.2, 3.0) if plan["dc_levels"] else 0.0)
    ratio = rng.uniform(0.9, 1.1)
    alpha = rng.uniform(-0.05, 0.05)
    coef: dict[int, complex] = {}
    if "signal_shape" in plan["effects"]:
        size = plan["amplitude"] * noise / np.sqrt(0.5 * len(plan["harmonics"]))
        for h in plan["harmonics"]:
            coef[h] = size * np.exp(1j * rng.uniform(0, 2 * np.pi))

    def shape(x):
        f = np.cos(x)
        for h, c in coef.items():
            f = f + c.real * np.cos(h * x) + c.imag * np.sin(h * x)
        return f

    gain = np.ones(n)
    if "radial_order" in plan["effects"]:
        m = int(rng.choice([14, 17, 19, 23]))  # above signal_shape's default orders
        gain = 1 + 4 * noise * np.cos(m * phi + rng.uniform(0, 2 * np.pi))
        truth["where"] = {"orders": [m]}
    if "amplitude_step" in plan["effects"]:
        i0 = int(rng.uniform(0.5, 0.8) * n)
        # the step in noise units (6 in the benchmark's plans; a plan may set its own)
        gain = np.where(np.arange(n) >= i0, 1 + plan.get("step_noise", 6.0) * noise, 1.0)
        truth["where"] = {"times_s": [float(cols["t"][i0])], "runs": [0]}
    sa = p + gain * shape(phi)
    sb = q + ratio * gain * shape(phi + alpha - np.pi / 2)
    sa = sa + rng.normal(0, noise, n)
    sb = sb + rng.normal(0, noise, n)
    if "clipping" in plan["effects"]:
        lev = rng.uniform(0.9, 0.96)
        sa = np.clip(sa, p - lev, p + lev)
        sb = np.clip(sb, q - lev * ratio, q + lev * ratio)
        truth["where"] = {"view": "clipping"}
    truth["glitch_rows"] = []
    for _ in range(plan["glitches"]):
        i = int(rng.integers(5, n - 5))
        sa[i] += rng.choice([-1, 1]) * 0.3
        truth["glitch_rows"].append(i)
    truth["transient_rows"] = int((~steady).sum())
    truth["noise"] = noise
    truth["ellipse"] = dict(p=p * s, q=q * s, ratio=ratio, alpha=alpha)
    if not plan["timed"]:
        o = np.argsort(np.arctan2(sb - q, sa - p))
        sa, sb = sa[o], sb[o]
    cols["sa"] = sa * s
    cols["sb"] = sb * s
    meta = {"format": "encdesign-recording/1", "kind": "quadrature"}
    return Recording("quadrature", meta, cols), truth
