"""Recordings with physics outside the finder's catalog (issue 41's discovery benchmark).

:func:`outside_record` draws a multihead bench (4 heads and a reference angle, ``multihead``)
or one sensor against a reference (``sensor``), 3 steady runs at different speeds (for the
direction classes 4: each direction at two speeds, :data:`DIRECTION_RUNS`), with a disk
error of orders 1-5, white noise, and one structure of a class nobody wrote into the
catalog; or (``sds``) a shifted-delta-sum bench (the concealed benchmark's instrument: a
6-pole-pair motor, 2 fixed and 3 moving sensors, 24 platform positions stepped by the golden
angle, 1 ns jitter, a 100 MHz clock) whose moving sensors' edges carry the structure as a
delay. The truth says the frame and
modulation a correct model has, and the speed exponent where there is one.
"""

from __future__ import annotations

import math

import numpy as np

from ..io import Recording

NOISE_RAD = 0.5e-6
"""Noise std of every reading (rad)."""

CLASSES = (
    "torque_ripple",
    "head_defect",
    "one_direction",
    "fixed_hz",
    "slow_growth",
    "intermittent",
    "direction_lag",
    "speed_lag",
    "order_step",
    "sensor_frame",
    "platform_order",
    "sensor_step",
    "platform_step",
)
"""The out-of-catalog classes: torque ripple at a drive order falling as speed^-2 (a shaft
motion); a defect of one head; an error in one direction only; a structure at a fixed
frequency with its own Q (``fixed_hz``: a mode rung at the start of every run with its own
phase, decaying as ``exp(-pi f t / Q)``; a steady line of constant amplitude is the catalog's
``vibration``: :data:`CONTROLS`); a slow growth over the
record; an order present in two of the three runs, at their different speeds, with its own
phase in each (``intermittent``: a contact that engages in some runs only, re-seated at
another angle each time; the finder's ``per_cell``); an error of opposite sign in the two
directions;
a lag growing as speed^+1; an order that switches on at one time of the middle run
(``order_step``); and on an SDS bench: a periodic error of the platform angle in the frame
of one moving sensor (``sensor_frame``: an SDS sensor-frame error), an order of the platform
angle common to the moving sensors that no catalog effect has (``platform_order``, orders 5
to 11, beyond the beam tilt's 1-3), and a sensor-frame order that switches on from one run
on (``sensor_step``)."""

KINDS = ("multihead", "sensor", "sds")

CONTROLS = ("catalog_vibration",)
"""Classes of catalog physics, to check that discovery leaves them to the catalog: a
steady line at a fixed frequency with its own amplitude and phase in every run (the
catalog's ``vibration``)."""

CONFOUNDED = ("intermittent_one_run",)
"""Classes no record of this bench can tell from catalog physics, kept to be run by name
(not in :data:`CLASSES`): ``intermittent_one_run`` (``intermittent`` before session 20) is
an order present in one steady run only, which within that run is a line at one fixed
frequency, ``m`` x the run's speed: exactly the catalog's ``vibration`` with that run's own
amplitudes and none in the others (and on one sensor, whose static orders are its own error
function, any pattern of one order over 3 runs that is on in one and off in two, or on in
two with one phase, is that error function plus such a vibration)."""

Q_RANGE = (20.0, 60.0)
"""Quality factor of the ``fixed_hz`` mode (its ring-down time ``Q / (pi f)``: 0.2 to 0.8 s
at 23 to 37 Hz, inside a run of 2 s at 3000 rows)."""

DIRECTION_RUNS = ((1.0, 1.0, 1.7, 1.7), (1, -1, 1, -1))
"""Speeds (x the first run's) and directions of the direction classes' 4 runs (session 20):
each direction at two speeds. Until session 19 they had 3 runs, ``(1, 1, 1.7)`` x
``(+, -, +)``: the one reverse run was one steady speed, so an order in one direction only, or
of opposite sign in the two, was a static order (the catalog's ``beam_tilt_axial``; on one
sensor its own error function) plus a line at one frequency in that run (``vibration``),
exactly."""

SDS_CLASSES = ("sensor_frame", "platform_order", "sensor_step", "platform_step", "slow_growth")
"""The classes an SDS bench (one steady speed, one direction, one row per run) carries."""


def classes_for(kind: str) -> tuple[str, ...]:
    """The classes of :data:`CLASSES` a bench of ``kind`` can carry."""
    if kind == "sds":
        return SDS_CLASSES
    out = tuple(c for c in CLASSES if c not in SDS_CLASSES or c == "slow_growth")
    if kind == "sensor":  # one sensor: a static order of its one head is its own error
        out = tuple(c for c in out if c != "head_defect")  # function (the base model's)
    return out


SDS_NOISE_RAD = 1.3e-8
"""Noise std of an SDS run-mean reading of this bench (rad): the level the finder estimates
on the run-mean channels of a clean record (1.30e-8 on seed 801; 1 ns jitter, 100 MHz
clock, 200 marks, 4 revolutions)."""

SDS_RUNS = 24
SDS_REVS = 4
SDS_MARKS = 200

POLE_PAIRS = 7


def _truth(cls: str, C: int, rng, mode: tuple[float, float] | None = None) -> dict:
    m = int(rng.choice([9, 11, 13, 17]))
    if cls == "torque_ripple":
        return dict(line=("order", 2 * POLE_PAIRS), frame="shaft", modulation="speed", beta=-2.0)
    if cls == "head_defect":
        k = int(rng.integers(0, C))
        return dict(line=("order", m), frame=f"head {k}" if C > 1 else "shaft", modulation="static")
    if cls == "one_direction":
        return dict(line=("order", m), frame="shaft", modulation="forward")
    if cls == "fixed_hz":
        f = float(rng.uniform(23.0, 37.0))
        q = float(rng.uniform(*Q_RANGE))
        if mode is not None:  # the bench's own mode (drawn all the same: the same stream)
            f, q = float(mode[0]), float(mode[1])
        return dict(line=("hz", f), frame="hz", modulation="ringdown", q=q)
    if cls == "catalog_vibration":
        return dict(line=("hz", float(rng.uniform(23.0, 37.0))), frame="hz", modulation="per_cell")
    if cls == "slow_growth":
        return dict(line=("order", m), frame="disk" if C > 1 else "shaft", modulation="growth")
    if cls == "intermittent":  # on in two runs (speeds apart), off in the third
        off = int(rng.integers(0, 3))
        runs = tuple(r for r in range(3) if r != off)
        return dict(line=("order", m), frame="shaft", modulation="per_cell", runs=runs)
    if cls == "intermittent_one_run":
        return dict(
            line=("order", m), frame="shaft", modulation="cell", run=int(rng.integers(0, 3))
        )
    if cls == "direction_lag":
        return dict(line=("order", m), frame="shaft", modulation="direction")
    if cls == "speed_lag":
        return dict(line=("order", m), frame="shaft", modulation="speed", beta=1.0)
    if cls == "order_step":
        return dict(line=("order", m), frame="shaft", modulation="step", step_run=1)
    raise ValueError(f"unknown class {cls!r}; expected one of {CLASSES + CONFOUNDED}")


def outside_record(
    rng: np.random.Generator,
    cls: str,
    size: float,
    kind: str = "multihead",
    n_rows: int = 6000,
    mode: tuple[float, float] | None = None,
    *,
    noise: bool = True,
    sds_noise_parts: tuple[bool, bool] = (True, True),
) -> tuple[Recording, dict]:
    """``(recording, truth)``: a bench of ``kind`` with one structure of class ``cls``
    (:data:`CLASSES`; ``"clean"``: none) of peak amplitude ``size`` x the noise.
    ``mode``: ``(frequency Hz, Q)`` of the ``fixed_hz`` class's mode (a property of the
    bench: another record of the same bench; default: drawn). ``noise=False``: the same
    record (the same draws) without its noise (the readings' white noise; on an SDS bench
    the edges' timing jitter and the clock's rounding): with ``size`` 0 too, what is left
    of the same ``rng`` is the bench alone, so the structure and the noise of a record are
    known exactly (``benchmarks/discovery.py``'s oracle detectability).
    ``sds_noise_parts``: on an SDS bench with ``noise``, which of ``(jitter, rounding)`` the
    record keeps (``benchmarks/sds_run_mean_levels.py``: each source's levels apart).

    ``truth``: ``line`` (``("order", m)`` or ``("hz", f)``), ``frame``, ``modulation``,
    ``beta`` (speed exponent, where the class has one), ``alpha`` (head azimuths, rad)."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; expected one of {KINDS}")
    if cls in CONFOUNDED and kind == "sds":
        raise ValueError(f"class {cls!r} not on an sds bench; expected {classes_for(kind)}")
    if cls not in ("clean", *CONTROLS, *CONFOUNDED) and cls not in classes_for(kind):
        raise ValueError(f"class {cls!r} not on a {kind} bench; expected {classes_for(kind)}")
    if kind == "sds":
        return _sds_record(rng, cls, size, noise, sds_noise_parts)
    C = 4 if kind == "multihead" else 1
    both = cls in ("one_direction", "direction_lag")
    R = 4 if both else 3
    n = n_rows // R
    fs = 500.0
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.4, 5.9, C - 1))]) if C > 1 else np.zeros(1)
    truth = {"alpha": alpha, "class": cls, "size": size, "kind": kind}
    if cls != "clean":
        truth.update(_truth(cls, C, rng, mode))
    speeds = np.array([1.0, 1.7, 2.9]) * 2 * np.pi * rng.uniform(0.8, 1.2)
    signs = np.array(DIRECTION_RUNS[1], float) if both else np.ones(R)
    if both:  # each direction at two speeds
        speeds = np.array(DIRECTION_RUNS[0]) * speeds[0]
    ts, ths, runs, ws = [], [], [], []
    for r in range(R):
        t = np.arange(n) / fs
        w = signs[r] * speeds[r]
        ts.append(t)
        ths.append(w * t + rng.uniform(0, 2 * np.pi))
        runs.append(np.full(n, r))
        ws.append(np.full(n, w))
    t, th, run, om = map(np.concatenate, (ts, ths, runs, ws))
    err = np.zeros((t.size, C))
    for m in range(1, 6):
        err += 8 * NOISE_RAD / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6))
    A = size * NOISE_RAD
    ph = rng.uniform(0, 2 * np.pi)
    if cls != "clean":
        kind_l, val = truth["line"]
        g0 = np.exp(np.mean(np.log(speeds)))
        if kind_l == "hz":
            phr = rng.uniform(0, 2 * np.pi, R)[run]
            s = A * np.sin(2 * np.pi * val * t + phr)[:, None] * np.ones(C)
            if truth["modulation"] == "ringdown":  # rung at the run's start, its own Q
                s = s * np.exp(-np.pi * val * t / truth["q"])[:, None]
        else:
            fr = truth["frame"]
            if fr == "disk":
                s = np.sin(val * (th[:, None] - alpha[None, :]) + ph)
            else:
                s = np.sin(val * th + ph)[:, None] * np.ones(C)
                if fr.startswith("head "):
                    s = s * (np.arange(C) == int(fr.split()[1]))[None, :]
            mod = truth["modulation"]
            if mod == "speed":
                g = (np.abs(om) / g0) ** truth["beta"]
            elif mod == "forward":
                g = (om > 0) * 1.0
            elif mod == "direction":
                g = np.sign(om)
            elif mod == "growth":
                tau = t + run * (n / fs + 1.0)
                g = tau / tau.max()
            elif mod == "cell":
                g = (run == truth["run"]) * 1.0
            elif mod == "per_cell":  # its runs only, each with its own phase (at least a
                # quarter turn from the first's: not one phase over the runs it is on in)
                dph = np.zeros(R)
                dph[list(truth["runs"][1:])] = rng.uniform(0.5 * np.pi, 1.5 * np.pi)
                s = np.sin(val * th + ph + dph[run])[:, None] * np.ones(C)
                g = np.isin(run, truth["runs"]) * 1.0
            elif mod == "step":  # on from a time inside the run (a third to two thirds in)
                ts = float(rng.uniform(0.33, 0.67)) * n / fs
                truth["step_time_s"], truth["run"] = ts, truth["step_run"]
                g = ((run > truth["step_run"]) | ((run == truth["step_run"]) & (t >= ts))) * 1.0
            else:
                g = np.ones(t.size)
            s = A * s * g[:, None]
        err += s
    read = th[:, None] + err + rng.normal(0, NOISE_RAD, err.shape) * float(noise)
    cols = {"t": t, "run": run, "theta_ref": th.copy()}
    for k in range(C):
        cols[f"h{k}"] = read[:, k]
    enc = {"head_angles_deg": np.degrees(alpha).tolist()}
    if C > 1:
        enc["optical_radius_m"] = 0.02
    else:
        enc["sensor"] = "magnetic"
    meta = {
        "format": "encdesign-recording/1",
        "kind": "multihead",
        "encoder": enc,
        "motor": {"pole_pairs": POLE_PAIRS},
    }
    truth["speeds_rad_s"] = speeds
    return Recording("multihead", meta, cols), truth


def _sds_record(
    rng: np.random.Generator,
    cls: str,
    size: float,
    noise: bool = True,
    parts: tuple[bool, bool] = (True, True),
) -> tuple[Recording, dict]:
    """An SDS bench (module doc) with one structure of ``cls`` on the moving sensors' edges:
    a delay ``A f(phi) / Omega`` (``A`` = ``size`` x :data:`SDS_NOISE_RAD`); ``noise``:
    the edges' 1 ns jitter and the clock's rounding, each where ``parts`` (jitter,
    rounding) says (else exact edge times)."""
    jitter, rounding = noise and parts[0], noise and parts[1]
    import jax

    from ..physics._sds_errors import SDSErrors
    from ._conceal_sds import CLOCK_S, SPEED_RAD_S, sds_bench_design
    from ._sds import sds_bench_columns, sds_encoder_table

    key = jax.random.PRNGKey(int(rng.integers(0, 2**31 - 1)))
    kd, kj = jax.random.split(key)
    design = sds_bench_design(kd, SDS_MARKS, 0.0, 3, 2)
    M = 3
    psi = np.asarray(design.moving_azimuths_rad, float)
    golden = np.pi * (3 - math.sqrt(5))
    R = SDS_RUNS
    phis = golden * np.arange(R) + np.radians(rng.uniform(-2, 2, R))
    phis = np.mod(phis + rng.uniform(0, 2 * np.pi), 2 * np.pi)
    truth: dict = {"class": cls, "size": size, "kind": "sds", "alpha": psi}
    n = int(rng.choice([5, 7]))
    k = int(rng.integers(0, M))
    if cls == "sensor_frame":
        truth.update(line=("order", n), frame=f"sensor m{k}", modulation="static")
    elif cls == "platform_order":
        truth.update(line=("order", n), frame="platform", modulation="static")
    elif cls == "sensor_step":
        truth.update(line=("order", n), frame=f"sensor m{k}", modulation="step")
        truth["step_run"] = int(rng.integers(R // 3, 2 * R // 3))
    elif cls == "platform_step":
        truth.update(line=("order", n), frame="platform", modulation="step")
        truth["step_run"] = int(rng.integers(R // 3, 2 * R // 3))
    elif cls == "slow_growth":
        truth.update(line=("order", n), frame=f"sensor m{k}", modulation="growth")
    A = size * SDS_NOISE_RAD
    ph = float(rng.uniform(0, 2 * np.pi))

    def hook(i: int, phi: float, f: np.ndarray, m: np.ndarray):
        if cls != "clean":
            g = 1.0
            if cls in ("sensor_step", "platform_step"):
                g = float(i >= truth["step_run"])
            elif cls == "slow_growth":
                g = i / (R - 1)
            d = A * g * math.sin(n * phi + ph) / SPEED_RAD_S
            if cls in ("platform_order", "platform_step"):
                m = m + d
            else:
                m[k] = m[k] + d
        if not rounding:
            return f, m
        return np.ceil(f / CLOCK_S) * CLOCK_S, np.ceil(m / CLOCK_S) * CLOCK_S

    errors = SDSErrors(clock_period_s=0.0, jitter_s=1e-9 if jitter else 0.0)
    cols = sds_bench_columns(design, phis, SDS_REVS, errors, key=kj, edge_hook=hook)
    meta = {
        "format": "encdesign-recording/1",
        "kind": "sds",
        "encoder": sds_encoder_table(design, CLOCK_S),
    }
    truth["speeds_rad_s"] = np.array([SPEED_RAD_S])
    if "step_run" in truth:
        truth["run"] = truth["step_run"]
    return Recording("sds", meta, cols), truth
