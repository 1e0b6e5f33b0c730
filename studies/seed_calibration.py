"""The seeds' instruments as calibrated models: unknowns fitted to training figures, rest predicted.

For each instrument of the seeds (seed 001's first and second SDS devices, seed 002's shaker
setup) the unknowns are fitted JOINTLY by Levenberg–Marquardt (``optimistix``) to a declared
training subset of the seed's figures, each weighted by the precision the seed states (or,
where it states none, by the precision of the quoted digits; a bound "< b" used for training
becomes the uniform [0, b]: b/2 ± b/√12). Every other figure of the instrument is then
PREDICTED with its uncertainty (the Gauss–Newton covariance JᵀJ⁻¹ propagated linearly, plus
the model's own spread where the model has one, e.g. an unknown phase) and compared in units
of the combined σ. Parameters a figure set cannot separate are reported as unidentified
directions (eigenvalues of JᵀJ below 1e-10 of the largest) instead of being given a number.

SDS first device (seed 001, 2 + 2 sensors, 10,000 edges, 10 rev/s). One noise model: the
reading noise of the instrument is the coherent bearing whirl (the reference spectrum's
shape, amplitude fitted) plus white edge-timing jitter (fitted). The per-revolution pair
errors for a unit whirl and a unit jitter are simulated with ``encdesign.simulate_readings``
(the whirl is a sum of sinusoids in the revolution index, fitted by linear least squares to
the simulated revolutions, so its extremes over 1,800 or 100,000 revolutions are evaluated
exactly); the figures are linear (whirl) and Gaussian (jitter) functions of the two
amplitudes. Training: fig. 9 one pair 0.42″ p-p; the 4–5 mas standard deviation of sets of
readings. Predicted from the same two numbers: fig. 9 two pairs < 0.02″ p-p; 100,000
readings within ±25 mas; fig. 12 ramp RMS 8–15.3 mas and max deviation 32 mas (with the
seed's 0.1 % actuator linearity over 37″ as a half-sine bow of uniform random amplitude);
fig. 10's 2.46 mas step detected in noise; fig. 15's instrument share of the 0.077″. The
pair offset: the placement off 180° is fitted to the 89.5″ (the model adds the pairs'
systematic constants, simulated); its length at a 1 in radius is predicted. The closure
figures: one pair ±2″ (fig. 17), two pairs order 2 ≈ 0.9″ (fig. 19) and the residual
after the order-2 sinusoid < 0.1″ fit the order-1 (speed × eccentricity) amplitude, the
order-2 amplitude and the two-pair order 1 (axial runout × the seed's 0.01 rad optical
tilt); the phase between orders 1 and 2 is unknown and averaged over.

SDS second device: order 2 ≈ 0.02″ and 0.25″ p-p fit its order-1 and order-2 amplitudes
(exactly determined); predicted: that its order 1 is the first device's (same optics).

Seed 002 shaker setup: the uncompensated peak error at each case is the vibration error's
amplitude; the compensated peak is the LUT's amplitude mismatch (the seed's "around 5 %"
reconstruction error, an input) plus the error of a sinusoid whose frequency is wrong by x
FFT bins over the record (2·|sin(πx/2)| at the record's ends, rms √(2(1 − sinc x)) about its
centre, phase fitted at the centre). The frequency estimator is the seed's FFT (stated by
the seed as the cause), so x is constrained to [0, ½] bin and fitted per case. Training: the
three 0.8 mm/s peak pairs; predicted: the 3.4 mm/s peak pair (same excitation) and the best
and worst error-area reductions (area taken ∝ rms).
"""

import dataclasses
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import scipy.integrate
import scipy.stats

import encdesign as ed
from encdesign.io import new_figure, save_figure, study_parser, write_results

jax.config.update("jax_enable_x64", True)

NAME = "seed-calibration"
ARCSEC = math.pi / 648_000
MAS = ARCSEC / 1000
INCH = 0.0254
REV_S = 0.1  # seed 001: 10 rev/s
FIG9_REVS = 1800  # 3 minutes at 10 rev/s (the seed's "roughly 5,000" readings overlap)
FIG9_READINGS = 5000
LONG_READINGS = 100_000
RAMP_READINGS = 16_383
RAMP_FULL_ARCSEC = 37.0  # seed: 37 arcsec triangle wave
ACTUATOR_LINEARITY = 1e-3  # seed: 0.1 % specified linearity
OPTICAL_TILT_RAD = 0.01  # seed: 0.001 in over 0.1 in
DISK_RADIUS_M = INCH  # seed: 2 in diameter disks
LUT_MISMATCH = 0.05  # seed 002: reconstruction error "around 5 %, less than 10 %"


def _progress(msg: str) -> None:
    print(f"[{NAME}] {msg}", file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- fit machinery


@dataclass(frozen=True)
class Figure:
    """One quantitative result of a seed: ``value ± sigma`` in ``unit``; ``role`` is
    ``"train"`` or ``"predict"``; ``bound``: ``"upper"`` for a result stated as "< value"
    (a prediction then agrees when it does not exceed the bound)."""

    key: str
    text: str
    value: float
    sigma: float
    unit: str
    role: str
    bound: str | None = None
    note: str = ""


@dataclass(frozen=True)
class Param:
    """A fitted unknown: ``value = scale · exp(θ)`` (``kind="log"``), ``scale · θ``
    (``"lin"``) or ``lo + (hi − lo) · sigmoid(θ)`` (``"box"``)."""

    name: str
    unit: str
    scale: float
    kind: str = "log"
    lo: float = 0.0
    hi: float = 1.0

    def value(self, th):
        if self.kind == "log":
            return self.scale * jnp.exp(th)
        if self.kind == "lin":
            return self.scale * th
        return self.lo + (self.hi - self.lo) * jax.nn.sigmoid(th)


@dataclass
class Instrument:
    """``forward(θ) -> {figure key: (model value, model spread)}`` in the figures' units."""

    name: str
    params: list[Param]
    theta0: np.ndarray
    forward: Callable
    figures: list[Figure]
    inputs: dict = field(default_factory=dict)

    def values(self, theta):
        return [p.value(theta[i]) for i, p in enumerate(self.params)]


_COMPILED: dict = {}


def _compiled(inst: Instrument):
    """Jitted model values, spreads and Jacobian of all figures of ``inst`` (kept per model
    and figure list, so the joint fit of ``tension`` compiles nothing again)."""
    keys = [f.key for f in inst.figures]
    cache_key = (id(inst.forward), tuple(keys))
    if cache_key in _COMPILED and _COMPILED[cache_key][0] is inst.forward:
        return _COMPILED[cache_key][1]

    def vals(t):
        out = inst.forward(t)
        return jnp.stack([jnp.asarray(out[k][0], float) for k in keys])

    def spreads(t):
        out = inst.forward(t)
        return jnp.stack([jnp.asarray(out[k][1], float) for k in keys])

    vals_j = jax.jit(vals)

    def masked_resid(theta, args):  # (y, σ, mask) as arguments: one LM compilation
        y, w, mask = args
        return mask * (vals_j(theta) - y) / w

    out = vals_j, jax.jit(spreads), jax.jit(jax.jacfwd(vals)), masked_resid
    _COMPILED[cache_key] = (inst.forward, out)
    return out


def training_residuals(inst: Instrument, weights: np.ndarray, vals=None) -> Callable:
    """r(θ) = (model − seed) / σ for the training figures; ``weights`` are the σ's."""
    vals = vals or _compiled(inst)[0]
    idx = np.array([i for i, f in enumerate(inst.figures) if f.role == "train"])
    y = np.array([f.value for f in inst.figures if f.role == "train"])
    w = jnp.asarray(weights, dtype=float)

    def resid(theta, args=None):
        return (vals(theta)[idx] - y) / w

    return resid


def fit(inst: Instrument, max_steps: int = 400) -> dict:
    """Levenberg–Marquardt on the training figures (weights re-evaluated once at the first
    solution, for model spreads that depend on θ), Gauss–Newton covariance, predictions."""
    vals, spreads, jac_all, resid = _compiled(inst)
    train = np.array([f.role == "train" for f in inst.figures])
    sig = np.array([f.sigma for f in inst.figures])
    theta = jnp.asarray(inst.theta0, dtype=float)
    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12)
    status = "success"
    y = jnp.asarray([f.value for f in inst.figures], dtype=float)
    mask = jnp.asarray(train, dtype=float)
    for _ in range(2):
        w_all = np.where(train, np.hypot(sig, np.asarray(spreads(theta))), 1.0)
        args = (y, jnp.asarray(w_all), mask)
        sol = optx.least_squares(resid, solver, theta, args=args, max_steps=max_steps, throw=False)
        if sol.result != optx.RESULTS.successful:
            status = "max_steps"
        theta = sol.value
    w = w_all[train]
    r = np.asarray(resid(theta, args))[train]
    jall = np.asarray(jac_all(theta))
    jac = jall[train] / w[:, None]
    lam, vec = np.linalg.eigh(jac.T @ jac)
    keep = lam > 1e-10 * max(lam.max(), 1e-300)
    cov = (vec[:, keep] / lam[keep]) @ vec[:, keep].T
    unidentified = [
        {p.name: float(v) for p, v in zip(inst.params, vec[:, i]) if abs(v) > 0.05}
        for i in np.where(~keep)[0]
    ]
    null = vec[:, ~keep]
    params = []
    for i, p in enumerate(inst.params):
        g = np.zeros(len(inst.params))
        g[i] = float(jax.grad(p.value)(theta[i]))
        se = float(np.sqrt(g @ cov @ g))
        free = bool(null.size and np.any(np.abs(null[i]) > 1e-6))
        params.append(
            {
                "name": p.name,
                "unit": p.unit,
                "value": float(p.value(theta[i])),
                "se": None if free else se,
                "identified": not free,
            }
        )
    values, spread = np.asarray(vals(theta)), np.asarray(spreads(theta))
    rows = []
    for k, f in enumerate(inst.figures):
        val, g = float(values[k]), jall[k]
        undetermined = bool(null.size and np.any(np.abs(g @ null) > 1e-9 * (1 + abs(val))))
        sd = math.sqrt(float(g @ cov @ g) + float(spread[k]) ** 2)
        comb = math.hypot(sd, f.sigma)
        if f.bound == "upper":
            z = max(0.0, val - f.value) / comb
        else:
            z = (val - f.value) / comb
        rows.append(
            {
                "key": f.key,
                "figure": f.text,
                "role": "fitted" if f.role == "train" else "predicted",
                "seed": f.value,
                "seed_sigma": f.sigma,
                "bound": f.bound,
                "unit": f.unit,
                "model": val,
                "model_sd": None if undetermined else sd,
                "residual_sigma": None if undetermined else z,
                "note": f.note,
            }
        )
    pred = [x for x in rows if x["role"] == "predicted" and x["residual_sigma"] is not None]
    n_train = int(r.size)
    return {
        "instrument": inst.name,
        "status": status,
        "params": params,
        "unidentified_directions": unidentified,
        "chi2_training": float(r @ r),
        "n_training": n_train,
        "dof": n_train - int(keep.sum()),
        "figures": rows,
        "predicted_within_2sigma": sum(abs(x["residual_sigma"]) <= 2 for x in pred),
        "predicted_total": len(pred),
        "inputs": inst.inputs,
    }


def tension(inst: Instrument) -> dict:
    """All figures of the instrument as training at once: χ² and dof of that joint fit.
    A χ²/dof far above 1 means no single parameter set reproduces them together."""
    every = [  # bounded figures stay predictions (a bound is not a value to fit)
        Figure(**{**f.__dict__, "role": "train" if f.bound is None else "predict"})
        for f in inst.figures
    ]
    joint = Instrument(inst.name, inst.params, inst.theta0, inst.forward, every)
    res = fit(joint)
    rows = [x for x in res["figures"] if x["role"] == "fitted"]
    worst = sorted(rows, key=lambda x: -abs(x["residual_sigma"] or 0))[:3]
    return {
        "chi2": res["chi2_training"],
        "dof": res["dof"],
        "worst": [(x["key"], x["residual_sigma"]) for x in worst],
    }


# ----------------------------------------------------------------------------- SDS device 1


def _quiet_errors(**kw):
    """The seed device's systematic errors without its platform axial runout."""
    return ed.reference_errors(systematic_only=True, **{"axial_runout_cos_m": [0.0, 0.0], **kw})


def expected_range(n: int) -> float:
    """E[max − min] of ``n`` standard normal samples."""

    def integrand(x):
        return x * n * scipy.stats.norm.pdf(x) * scipy.stats.norm.cdf(x) ** (n - 1)

    return 2.0 * scipy.integrate.quad(integrand, -2, 10, limit=200)[0]


def sds_noise_coefficients(marks: int, n_revs: int, key) -> dict:
    """Responses of the 2 + 2 device at rest to a unit whirl (1 µm RMS, the reference
    spectrum's shape) and a unit edge jitter (1 ns), simulated with ``simulate_readings``."""
    design = ed.reference_design(2, 2, marks_per_rev=marks)
    ref = ed.reference_errors()
    amp = np.asarray(ref.bearing_amplitude_m)
    ratio = np.asarray(ref.bearing_ratio)
    unit = 1e-6 / math.sqrt(float(np.sum(amp**2)))
    whirl = _quiet_errors(
        bearing_amplitude_m=amp * unit,
        bearing_ratio=ratio,
        bearing_phase_rad=ref.bearing_phase_rad,
    )
    r = ed.simulate_readings(design, 0.3, n_revs, whirl)
    pair = np.asarray(r.pair_error_rad)
    seqs = {"one": pair[:, 0, 0], "two": 0.5 * (pair[:, 0, 0] + pair[:, 1, 1])}
    k = np.arange(n_revs)

    def basis(kk):
        ph = 2 * np.pi * np.outer(kk, ratio)
        return np.concatenate([np.ones((kk.size, 1)), np.cos(ph), np.sin(ph)], axis=1)

    out = {"marks": marks, "revs_simulated": n_revs}
    for name, s in seqs.items():
        c, *_ = np.linalg.lstsq(basis(k), s, rcond=None)
        out[f"whirl_{name}_fit_rel_residual"] = float(np.std(s - basis(k) @ c) / np.std(s))
        long = np.concatenate(
            [
                basis(np.arange(i, min(i + 10_000, LONG_READINGS))) @ c
                for i in range(0, LONG_READINGS, 10_000)
            ]
        )
        long = long - long.mean()
        out[f"whirl_{name}_pp_fig9_arcsec_per_um"] = float(np.ptp(long[:FIG9_REVS])) / ARCSEC
        out[f"whirl_{name}_std_mas_per_um"] = float(np.std(long)) / MAS
        out[f"whirl_{name}_maxabs_long_mas_per_um"] = float(np.max(np.abs(long))) / MAS
    rj = ed.simulate_readings(design, 0.3, n_revs, _quiet_errors(jitter_s=1e-9), key=key)
    pj = np.asarray(rj.pair_error_rad)
    out["jitter_one_std_mas_per_ns"] = float(np.std(pj[:, 0, 0])) / MAS
    out["jitter_two_std_mas_per_ns"] = float(np.std(0.5 * (pj[:, 0, 0] + pj[:, 1, 1]))) / MAS
    out["jitter_coefficient_rel_se"] = 1 / math.sqrt(2 * (n_revs - 1))
    return out


def pair_offset_constants(marks: int, placement_arcsec: float) -> dict:
    """Offset between the pairs minus the placement off 180°, at four platform angles
    (the pairs' systematic constants, speed × marks), from ``simulate_readings``."""
    design = ed.reference_design(2, 2, marks_per_rev=marks)
    phis = np.deg2rad([17.0, 107.0, 197.0, 287.0])
    pair = np.asarray(
        ed.physics.moved_sensor_pair_errors(
            design, 1, placement_arcsec * ARCSEC, phis, _quiet_errors()
        )
    )
    off = [float(x) / ARCSEC - placement_arcsec for x in pair[:, 1, 1] - pair[:, 0, 0]]
    return {"mean_arcsec": float(np.mean(off)), "std_arcsec": float(np.std(off)), "values": off}


def _pp_over_phase(c1, c2, n_phase: int = 24):
    """Mean and std over the unknown relative phase of the p-p of c1 cos θ + c2 cos(2θ + φ)
    sampled at the 72 polygon faces."""
    th = jnp.linspace(0, 2 * jnp.pi, 72, endpoint=False)
    phis = jnp.linspace(0, 2 * jnp.pi, n_phase, endpoint=False)
    curves = c1 * jnp.cos(th)[None] + c2 * jnp.cos(2 * th[None] + phis[:, None])
    pp = jnp.max(curves, axis=1) - jnp.min(curves, axis=1)
    return jnp.mean(pp), jnp.std(pp)


def device1(coef: dict, offset: dict, key) -> Instrument:
    r_fig9 = expected_range(FIG9_READINGS)
    r_long = expected_range(LONG_READINGS) / 2
    r_ramp = expected_range(RAMP_READINGS) / 2
    # fig. 12 ramps: 8 ramps, bow amplitude uniform within the 0.1 % linearity; the bow's
    # residual about the fitted line (rms and max), from the half-sine shape
    u = np.linspace(0, 1, 4001)
    bow = np.sin(np.pi * u)
    res = bow - np.polyval(np.polyfit(u, bow, 1), u)
    bow_rms, bow_max = float(np.sqrt(np.mean(res**2))), float(np.max(np.abs(res)))
    lin_mas = ACTUATOR_LINEARITY * RAMP_FULL_ARCSEC * 1000
    draws = np.abs(np.asarray(jax.random.uniform(key, (2000, 8), minval=-1.0, maxval=1.0)))
    draws = jnp.asarray(draws * lin_mas)
    n_tri = 3 * 40  # fig. 10: about three square-wave cycles, 40 readings per cycle (assumed)
    c = coef

    def forward(theta):
        w, j, c1, a2, b1, dlt = (p.value(theta[i]) for i, p in enumerate(params))
        w, j = w / 1e-6, j / 1e-9  # the coefficients are per µm and per ns
        s1 = j * c["jitter_one_std_mas_per_ns"]
        s2 = j * c["jitter_two_std_mas_per_ns"]
        std2 = jnp.sqrt((w * c["whirl_two_std_mas_per_um"]) ** 2 + s2**2)
        pp1 = jnp.sqrt((w * c["whirl_one_pp_fig9_arcsec_per_um"]) ** 2 + (r_fig9 * s1 / 1e3) ** 2)
        pp2 = jnp.sqrt((w * c["whirl_two_pp_fig9_arcsec_per_um"]) ** 2 + (r_fig9 * s2 / 1e3) ** 2)
        long = w * c["whirl_two_maxabs_long_mas_per_um"] + r_long * s2
        ramp = jnp.sqrt(std2**2 + (draws * bow_rms) ** 2)  # (draws, 8 ramps)
        rmin, rmax = jnp.min(ramp, axis=1), jnp.max(ramp, axis=1)
        dev = jnp.max(draws, axis=1) * bow_max + r_ramp * std2
        pp17 = _pp_over_phase(c1, a2)
        z = jnp.zeros(())
        return {
            "fig9_one_pair_pp": (pp1, z),
            "reading_std": (std2, z),
            "fig9_two_pairs_pp": (pp2, z),
            "long_run_max_abs": (long, z),
            "fig12_rms_min": (jnp.mean(rmin), jnp.std(rmin)),
            "fig12_rms_max": (jnp.mean(rmax), jnp.std(rmax)),
            "fig12_max_dev_up": (jnp.mean(dev), jnp.std(dev)),
            "fig10_step_detected": (jnp.asarray(1e-9 / 0.084 / MAS), 2 * std2 / math.sqrt(n_tri)),
            "fig15_instrument_rms": (math.sqrt(2) * std2 / 1e3, z),
            "pair_offset": (dlt + offset["mean_arcsec"], jnp.asarray(offset["std_arcsec"])),
            "pair_offset_inch": (dlt * ARCSEC * 1.0, z),
            "fig17_one_pair_pp": pp17,
            "fig19_order2": (a2, z),
            "fig19_residual": (jnp.abs(b1), z),
        }

    params = [
        Param("whirl_rms", "m", 1e-6),
        Param("edge_jitter_rms", "s", 1e-9),
        Param("one_pair_order1", "arcsec", 1.0, "lin"),
        Param("order2", "arcsec", 1.0, "lin"),
        Param("two_pair_order1", "arcsec", 1.0, "lin"),
        Param("placement_off_180", "arcsec", 1.0, "lin"),
    ]
    figs = [
        Figure(
            "fig9_one_pair_pp",
            "fig. 9 noise at rest, one pair (p-p)",
            0.42,
            0.042,
            "arcsec",
            "train",
            note="'about': ±10 %",
        ),
        Figure(
            "reading_std",
            "std of sets of 100–10,000 readings at rest",
            4.5,
            0.5,
            "mas",
            "train",
            note="'4 to 5 mas'",
        ),
        Figure("pair_offset", "fig. 9 offset between the pairs", 89.5, 0.5, "arcsec", "train"),
        Figure(
            "fig17_one_pair_pp",
            "fig. 17 one pair, −2 … +2 arcsec (p-p)",
            4.0,
            0.4,
            "arcsec",
            "train",
        ),
        Figure(
            "fig19_order2", "figs. 19–20 two pairs, order-2 amplitude", 0.9, 0.09, "arcsec", "train"
        ),
        Figure(
            "fig19_residual",
            "fig. 19 data − best-fit sinusoid < 0.1 arcsec",
            0.05,
            0.1 / math.sqrt(12),
            "arcsec",
            "train",
            note="bound as uniform [0, 0.1]",
        ),
        Figure(
            "fig9_two_pairs_pp",
            "fig. 9 noise at rest, two pairs < 0.02 arcsec p-p",
            0.02,
            0.002,
            "arcsec",
            "predict",
            "upper",
        ),
        Figure("long_run_max_abs", "~100,000 readings within ±25 mas", 25.0, 2.5, "mas", "predict"),
        Figure(
            "fig12_rms_min",
            "fig. 12 ramp RMS about the line, smallest of 8",
            8.0,
            0.8,
            "mas",
            "predict",
        ),
        Figure(
            "fig12_rms_max",
            "fig. 12 ramp RMS about the line, largest of 8",
            15.3,
            1.5,
            "mas",
            "predict",
        ),
        Figure(
            "fig12_max_dev_up",
            "fig. 12 max deviation, expanding ramps",
            32.0,
            3.2,
            "mas",
            "predict",
        ),
        Figure(
            "fig10_step_detected",
            "fig. 10 1 nm step detected ('roughly 2 mas' triangle)",
            2.0,
            0.5,
            "mas",
            "predict",
        ),
        Figure(
            "fig15_instrument_rms",
            "fig. 15 RMS difference after a 5° shift ≤ 0.077 arcsec",
            0.077,
            0.008,
            "arcsec",
            "predict",
            "upper",
            note="instrument share only (noise)",
        ),
        Figure(
            "pair_offset_inch",
            "placement error at the edge of a 2 in disk",
            0.00045,
            0.00005,
            "inch",
            "predict",
        ),
    ]
    inputs = {
        "whirl_spectrum_shape": "reference_errors() (8 components, not from the seed)",
        "speed_rev_s": 10.0,
        "edges_per_rev": coef["marks"],
        "fig9_readings": FIG9_READINGS,
        "fig9_revolutions": FIG9_REVS,
        "actuator_linearity": ACTUATOR_LINEARITY,
        "ramp_full_arcsec": RAMP_FULL_ARCSEC,
        "fig10_readings_assumed": n_tri,
        "pair_constants_arcsec": offset,
        "noise_coefficients": coef,
    }
    theta0 = np.array([math.log(0.5), math.log(20.0), 1.5, 0.8, 0.05, 90.0])
    return Instrument("seed001-device1", params, theta0, forward, figs, inputs)


def device2(b1_device1: tuple[float, float]) -> Instrument:
    def forward(theta):
        b1, a2 = (p.value(theta[i]) for i, p in enumerate(params))
        z = jnp.zeros(())
        return {
            "order2": (a2, z),
            "raw_pp": _pp_over_phase(b1, a2),
            "order1_as_device1": (b1, jnp.asarray(b1_device1[1])),
        }

    params = [Param("order1", "arcsec", 1.0, "lin"), Param("order2", "arcsec", 1.0, "lin")]
    figs = [
        Figure("order2", "figs. 23–24 order 2 ≈ 0.02 arcsec", 0.02, 0.005, "arcsec", "train"),
        Figure("raw_pp", "fig. 23 raw error 0.25 arcsec p-p", 0.25, 0.025, "arcsec", "train"),
        Figure(
            "order1_as_device1",
            "order 1 = device 1's two-pair order 1 (same optics)",
            b1_device1[0],
            0.0,
            "arcsec",
            "predict",
            note="hypothesis test, not a seed figure",
        ),
    ]
    return Instrument("seed001-device2", params, np.array([0.1, 0.02]), forward, figs)


# ----------------------------------------------------------------------------- seed 002

SEED002 = {  # case: (peak before, after) µm, seed figs. 4–5
    "700Hz_0.8": (1.5, 0.7),
    "1000Hz_0.8": (2.3, 1.3),
    "1400Hz_0.8": (1.8, 0.9),
    "700Hz_3.4": (1.8, 1.0),
}


def shaker() -> Instrument:
    cases = ["700Hz_0.8", "1000Hz_0.8", "1400Hz_0.8"]

    def one(a, x):
        s = jnp.sin(jnp.pi * x / 2)
        after = LUT_MISMATCH * a + 2 * a * s
        sinc = jnp.sinc(x)
        red = 1 - jnp.sqrt(LUT_MISMATCH**2 + 2 * (1 - sinc))
        return a, after, red

    def forward(theta):
        v = [p.value(theta[i]) for i, p in enumerate(params)]
        z = jnp.zeros(())
        out, reds = {}, []
        for i, c in enumerate(cases):
            b, a, red = one(v[i], v[3 + i])
            out[f"{c}_before"] = (b, z)
            out[f"{c}_after"] = (a, z)
            reds.append(red)
        b, a, red = one(v[0], v[3])  # 3.4 mm/s: the same excitation as 700 Hz, 0.8 mm/s
        out["700Hz_3.4_before"] = (b, z)
        out["700Hz_3.4_after"] = (a, z)
        out["area_best"] = (reds[0], z)
        allr = jnp.stack(reds + [red])
        out["area_worst"] = (-jax.nn.logsumexp(-200 * allr) / 200, z)
        return out

    params = [Param(f"vibration_peak_{c}", "um", 1.0) for c in cases] + [
        Param(f"f_exc_offset_{c}", "bins", 1.0, "box", 0.0, 0.5) for c in cases
    ]
    figs = []
    for c in cases:
        b, a = SEED002[c]
        figs.append(Figure(f"{c}_before", f"{c} mm/s peak error before", b, 0.1, "um", "train"))
        figs.append(Figure(f"{c}_after", f"{c} mm/s peak error after", a, 0.1, "um", "train"))
    b, a = SEED002["700Hz_3.4"]
    figs += [
        Figure("700Hz_3.4_before", "fig. 4c 700 Hz, 3.4 mm/s peak before", b, 0.1, "um", "predict"),
        Figure("700Hz_3.4_after", "fig. 4c 700 Hz, 3.4 mm/s peak after", a, 0.1, "um", "predict"),
        Figure(
            "area_best",
            "fig. 6 best error-area reduction (700 Hz, 0.8 mm/s)",
            0.80,
            0.05,
            "1",
            "predict",
        ),
        Figure(
            "area_worst", "fig. 6 worst error-area reduction (~50 %)", 0.50, 0.05, "1", "predict"
        ),
    ]
    inputs = {
        "lut_amplitude_mismatch": LUT_MISMATCH,
        "frequency_estimator": "FFT bin (seed: the cause of its 1,000/1,400 Hz results)",
        "offset_range_bins": [0.0, 0.5],
        "area_measure": "rms of the error (area ∝ rms for a fixed shape)",
        "speed_dependence": "none (the 3.4 mm/s case shares the 700 Hz amplitude and offset)",
    }
    theta0 = np.array([math.log(1.5), math.log(2.0), math.log(1.8), 0.0, 0.0, 0.0])
    return Instrument("seed002-shaker", params, theta0, forward, figs, inputs)


# ----------------------------------------------------------------------------- closed forms


def closed_forms() -> dict:
    """The seeds' arithmetic results (conversions, counts), recomputed: each is a check of
    the seed's own arithmetic, not of a model (``docs/seeds.md`` marks them so)."""
    urad, um, nm = 1e-6, 1e-6, 1e-9
    r000 = 0.0254  # seed 000: 2.54 cm optical radius
    sq = np.tile(np.repeat([1.0, -1.0], 50), 40) * 10.0  # ±10 mas square wave
    win = 9 * 50  # moving average over 9 half-periods
    tri = np.convolve(sq, np.ones(win) / win, mode="valid")
    counts = {
        name: dataclasses.asdict(ed.calibrate.closure_counts(n, k))
        for name, (n, k) in {
            "N12_complete": (12, 12),
            "N72_complete": (72, 72),
            "N72_15_settings": (72, 15),
            "N72_23_settings": (72, 23),
        }.items()
    }
    return {
        "s000_centering_1um_urad": um / r000 / urad,
        "s000_centering_1um_arcsec": um / r000 / ARCSEC,
        "s000_5urad_arcsec": 5 * urad / ARCSEC,
        "s001_0.1arcsec_parts": 0.1 / 1_296_000,
        "s001_0.1arcsec_at_1in_uin": 0.1 * ARCSEC * 1e6,
        "s001_1mas_at_1in_nm": MAS * INCH / nm,
        "s001_nickel_cell_third_nm": 0.3524 / 3,
        "s001_mark_spacing_over_1mas": (2 * math.pi / 10_000) / MAS,
        "s001_sqrt_10000": math.sqrt(10_000),
        "s001_1ns_one_edge_pair_mas": math.sqrt(2) * 1e-9 / REV_S * 2 * math.pi / MAS,
        "s001_10ns_per_rev_parts": 10 * nm / REV_S,
        "s001_10ns_arcsec": 10 * nm / REV_S * 2 * math.pi / ARCSEC,
        "s001_0.0001in_at_1in_radius_arcsec": 1e-4 / ARCSEC,
        "s001_89.5arcsec_at_1in_inch": 89.5 * ARCSEC,
        "s001_50mas_at_1.75in_uin": 50 * MAS * 1.75 * 1e6,
        "s001_0.0001in_at_10ft_arcsec": math.atan(1e-4 / 120) / ARCSEC,
        "s001_1nm_at_84mm_mas": nm / 0.084 / MAS,
        "s001_15um_at_84mm_arcsec": 15 * um / 0.084 / ARCSEC,
        "s001_fig11_triangle_pp_mas": float(np.ptp(tri)),
        "s001_1um_at_305.811mm_arcsec": um / 0.305811 / ARCSEC,
        "s001_0.077arcsec_at_305mm_um": 0.077 * ARCSEC * 0.305 / um,
        "s001_axial_1e-6in_at_1in_arcsec": (0.001 * 0.0001 / 0.1) / ARCSEC,
        "s001_closure_counts": counts,
        "s002_0.8mm_s_hz": 0.8e-3 / 20e-6,
        "s002_2mm_s_hz": 2e-3 / 20e-6,
        "s002_3.4mm_s_hz": 3.4e-3 / 20e-6,
    }


# ----------------------------------------------------------------------------- study


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    args = p.parse_args(argv)
    t0 = time.time()
    key = jax.random.PRNGKey(args.seed)
    marks = 500 if args.quick else 10_000
    n_revs = 16 if args.quick else 60
    _progress(f"noise coefficients: {marks} edges, {n_revs} revolutions")
    coef = sds_noise_coefficients(marks, n_revs, jax.random.fold_in(key, 1))
    _progress(f"pair constants ({time.time() - t0:.0f} s)")
    offset = pair_offset_constants(marks, 89.5)
    d1 = device1(coef, offset, jax.random.fold_in(key, 2))
    _progress(f"fits ({time.time() - t0:.0f} s)")
    results = [fit(d1)]
    b1 = next(x for x in results[0]["params"] if x["name"] == "two_pair_order1")
    d2 = device2((b1["value"], b1["se"] or 0.0))
    results.append(fit(d2))
    sh = shaker()
    results.append(fit(sh))
    _progress(f"tension: all figures fitted ({time.time() - t0:.0f} s)")
    tensions = {r["instrument"]: tension(i) for r, i in zip(results, [d1, d2, sh])}
    _progress(f"done ({time.time() - t0:.0f} s)")
    for r in results:
        r["tension_all_figures"] = tensions[r["instrument"]]
        p1 = {x["name"]: x for x in r["params"]}
        if "whirl_rms" in p1:  # share of the two-pair reading variance from the whirl
            w = p1["whirl_rms"]["value"] / 1e-6 * coef["whirl_two_std_mas_per_um"]
            j = p1["edge_jitter_rms"]["value"] / 1e-9 * coef["jitter_two_std_mas_per_ns"]
            r["derived_noise"] = {
                "whirl_two_pair_std_mas": w,
                "jitter_two_pair_std_mas": j,
                "whirl_share_of_variance": w**2 / (w**2 + j**2),
            }
        if "two_pair_order1" in p1:  # the axial runout it implies through the seed's optics
            v = p1["two_pair_order1"]
            r["derived"] = {
                "axial_runout_order1_m": abs(v["value"])
                * ARCSEC
                * DISK_RADIUS_M
                / OPTICAL_TILT_RAD,
            }
    n_in = sum(r["predicted_within_2sigma"] for r in results)
    n_all = sum(r["predicted_total"] for r in results)
    summary = {
        "study": NAME,
        "quick": bool(args.quick),
        "instruments": results,
        "predicted_within_2sigma": n_in,
        "predicted_total": n_all,
        "closed_forms": closed_forms(),
        "runtime_s": time.time() - t0,
    }
    for r in results:
        _progress(
            f"{r['instrument']}: χ² {r['chi2_training']:.3g}"
            f" ({r['n_training']} figures, dof {r['dof']})"
        )
        for x in r["figures"]:
            z = x["residual_sigma"]
            _progress(
                f"  {x['role']:9s} {x['key']:24s} seed {x['seed']:.4g}  model {x['model']:.4g}"
                f" ± {x['model_sd'] if x['model_sd'] is not None else float('nan'):.2g} {x['unit']}"
                f"  z {z if z is not None else float('nan'):+.2f}"
            )
    figs = [] if args.no_plots else [_plot(args.out, results)]
    write_results(args, NAME, summary, figs)
    return 0


def _plot(out, results):
    fig, axes = new_figure(1, len(results), figsize=(4.5 * len(results), 4.5))
    for ax, r in zip(np.atleast_1d(axes), results):
        rows = [x for x in r["figures"] if x["residual_sigma"] is not None]
        y = np.arange(len(rows))
        z = [x["residual_sigma"] for x in rows]
        col = ["tab:blue" if x["role"] == "fitted" else "tab:orange" for x in rows]
        ax.barh(y, z, color=col)
        ax.axvspan(-2, 2, color="k", alpha=0.08)
        ax.set_yticks(y, [x["key"] for x in rows], fontsize=6)
        ax.set_xlabel("(model − seed) / σ   blue fitted, orange predicted")
        ax.set_title(f"{r['instrument']}  χ²={r['chi2_training']:.2g}", fontsize=8)
    return save_figure(fig, out, "seed-calibration.png")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
