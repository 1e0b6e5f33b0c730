"""Discovered models as candidate modules (issue 41 item 4): ``encdesign diagnose
--export-candidates F.py`` writes each discovered term of a diagnosis as a
:class:`~encdesign.diagnose.Candidate` in the ``--candidates`` form, so that a later
diagnosis of a similar record tests it like a catalog effect, under its own name
(``discovered_...``, never a catalog name) and with its own doubt rule (an exponent outside
the range searched, or a size far from the one discovered, is refused).

The written file holds only data (the terms' specifications); the term functions are built
by :func:`discovered_candidate` from them.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax.numpy as jnp

from ...io._paths import atomic_write_text
from ._candidates import Candidate, Param


def candidate_name(term: Mapping[str, Any]) -> str:
    """``discovered_<line>_<frame>_<modulation>`` (lower case, ``[a-z0-9_]``)."""
    raw = f"discovered_{term['line']}_{term['frame']}_{term['modulation']}"
    return re.sub(r"[^a-z0-9]+", "_", raw.lower()).strip("_")


def _phase(spec: Mapping[str, Any], x: dict, f_hz=None):
    """The line's phase (rad) at each row; ``f_hz``: a fixed-frequency line's fitted
    frequency (Hz; default: the discovered one)."""
    v = float(spec["value"])
    if spec["line_kind"] == "hz":
        return 2 * math.pi * (v if f_hz is None else f_hz) * x["t"]
    return v * x["theta"]


def _frame(spec: Mapping[str, Any], x: dict, ph, C: int):
    """``(cos part, sin part)`` each (n, C) of the term's frame."""
    fr = spec["frame"]
    if fr == "disk":
        arg = spec["value"] * (x["theta"][:, None] - x["alpha"][None, :C])
        return jnp.cos(arg), jnp.sin(arg)
    if fr in ("platform", "azimuth") or fr.startswith("sensor "):
        return _sds_frame(spec, x, ph, C)
    c, s = jnp.cos(ph)[:, None], jnp.sin(ph)[:, None]
    mask = jnp.ones((1, C))
    if fr.startswith("head "):
        mask = (jnp.arange(C) == int(fr.split()[1]))[None, :] * 1.0
    return c * mask, s * mask


def _sds_frame(spec: Mapping[str, Any], x: dict, ph, C: int):
    """The SDS frames on the moving sensors' run-mean channels (the first ``n_moving``),
    projected on their differences where the record had no ``phi_ref``."""
    ex, fr = spec["export"], spec["frame"]
    M = int(ex["n_moving"])
    if fr == "azimuth":
        arg = spec["value"] * (x["theta"][:, None] + x["psi_m"][None, :M])
        cm, sm = jnp.cos(arg), jnp.sin(arg)
    else:
        mask = jnp.ones((1, M))
        if fr.startswith("sensor "):
            mask = (jnp.arange(M) == int(fr.split()[1][1:]))[None, :] * 1.0
        cm, sm = jnp.cos(ph)[:, None] * mask, jnp.sin(ph)[:, None] * mask
    if ex.get("projected"):
        cm, sm = cm - cm.mean(1, keepdims=True), sm - sm.mean(1, keepdims=True)
    pad = jnp.zeros((cm.shape[0], C - M))
    return jnp.concatenate([cm, pad], 1), jnp.concatenate([sm, pad], 1)


def _modulation(spec: Mapping[str, Any], p: dict, x: dict):
    """The per-row factor (n, 1) of the modulation (``per_cell``: 1, the runs' own
    amplitudes are the parameters)."""
    mod, ex = spec["modulation"], spec["export"]
    if mod == "speed":
        return (jnp.abs(x["omega"]) / ex["speed_ref_rad_s"]) ** p["beta"]
    if mod == "direction":
        return x["direction"]
    if mod == "forward":
        return (x["direction"] > 0) * 1.0
    if mod == "reverse":
        return (x["direction"] < 0) * 1.0
    if mod.startswith("cell "):
        return x["run_onehot"][:, ex["run_index"]]
    if mod == "growth":
        return (x["tau"] - ex["tau_mid_s"]) / ex["tau_half_s"]
    if mod == "temperature":
        return (x["driver"] - ex["driver_mid"]) / ex["driver_half"]
    if mod == "step":
        return (x["tau"] >= ex["step_tau_s"]) * 1.0
    if mod == "ringdown":  # rung at each run's start, decaying in decay_s
        t_in = x["tau"] - x["run_onehot"] @ jnp.asarray(ex["run_start_tau_s"])
        return jnp.exp(-jnp.maximum(t_in, 0.0) / p["decay_s"])
    return jnp.ones_like(x["t"])


def nonlinear_start(spec: Mapping[str, Any]) -> dict[str, float]:
    """The discovered values of a term's nonlinear parameters (a speed exponent ``beta``, a
    ring-down's decay time ``decay_s``): where its candidate's fit starts."""
    out = {}
    if spec["modulation"] == "speed":
        out["beta"] = float(spec["scaling"]["beta"])
    if spec["modulation"] == "ringdown":
        out["decay_s"] = float(spec["params"]["decay_time_s"])
    return out


def discovered_candidate(spec: Mapping[str, Any], free_frequency: bool = False) -> Candidate:
    """The candidate of one discovered term's JSON entry (``unexplained[i].model.terms[j]``).
    ``free_frequency``: a fixed-frequency (``hz``) line's frequency is a fitted parameter
    ``frequency_hz`` (Hz; start it at the discovered ``value``), as the catalog's
    ``vibration`` fits its own (the re-test of catalog names, :mod:`._discover_rival`)."""
    name = candidate_name(spec)
    free_f = free_frequency and spec["line_kind"] == "hz"
    per_run = spec["modulation"] == "per_cell" or spec["line_kind"] == "hz"
    offset = spec["line_kind"] == "order" and float(spec["value"]) == 0.0
    shape = "runs" if per_run else "1"
    amp0 = float(spec["params"]["amplitude"])
    unit = spec["params"]["unit"]

    def fn(p, x):
        C = x["alpha"].shape[0] if "alpha" in x else 1
        g = _modulation(spec, p, x)[:, None]
        if offset:
            base = jnp.ones((x["t"].shape[0], C))
            if spec["frame"].startswith("head "):
                base = base * (jnp.arange(C) == int(spec["frame"].split()[1]))[None, :]
            elif spec["export"].get("n_moving"):  # SDS: the frame's run-mean channels
                base, _ = _sds_frame(spec, x, jnp.zeros(x["t"].shape[0]), C)
            a = x["run_onehot"] @ p["cos_rad"] if per_run else p["cos_rad"]
            if level:  # a growth with its own level
                return base * (a + g * p["cos_rate_rad"])
            return g * base * (a[:, None] if per_run else a)
        f_hz = p["frequency_hz"] if free_f else spec["params"].get("frequency_hz")
        cpart, spart = _frame(spec, x, _phase(spec, x, f_hz), C)
        if per_run:
            a = (x["run_onehot"] @ p["cos_rad"])[:, None]
            b = (x["run_onehot"] @ p["sin_rad"])[:, None]
        else:
            a, b = p["cos_rad"], p["sin_rad"]
        if ringing:  # each run's amplitude changing linearly within the run
            ex = spec["export"]
            u = ((x["tau"] - ex["tau_mid_s"]) / ex["tau_half_s"])[:, None]
            a = a + u * (x["run_onehot"] @ p["cos_rate_rad"])[:, None]
            b = b + u * (x["run_onehot"] @ p["sin_rate_rad"])[:, None]
        if level:  # a growth with its own level: a + rate x the centred time
            return (
                a * cpart + b * spart + g * (p["cos_rate_rad"] * cpart + p["sin_rate_rad"] * spart)
            )
        return g * (a * cpart + b * spart)

    ringing = spec["modulation"] == "ringing"
    level = spec["modulation"] == "growth" and bool(spec["export"].get("growth_level"))
    params = [Param("cos_rad", unit, shape, description="cos amplitude")]
    if not offset:
        params.append(Param("sin_rad", unit, shape, description="sin amplitude"))
    if level:
        for nm in ("cos_rate_rad",) if offset else ("cos_rate_rad", "sin_rate_rad"):
            params.append(Param(nm, unit, shape, description="growth per half span of the time"))
    if ringing:
        for nm in ("cos_rate_rad", "sin_rate_rad"):
            params.append(
                Param(nm, unit, shape, description="change within the run (per half span)")
            )
    if free_f:
        params.append(
            Param("frequency_hz", "Hz", "1", linear=False, scale=1e-3, description="frequency")
        )
    start = None
    s0 = nonlinear_start(spec)  # the exponent's and the decay time's discovered values
    if "beta" in s0:
        params.append(
            Param("beta", "1", "1", linear=False, scale=0.1, description="speed exponent")
        )
    d0 = s0.get("decay_s")
    if d0 is not None:
        params.append(
            Param("decay_s", "s", "1", linear=False, scale=0.1 * d0, description="decay time")
        )
    if s0:

        def start(ctx, resid, findings):  # noqa: ARG001 - the StartFn contract
            return [{k: jnp.asarray(v) for k, v in s0.items()}]

    def plausible(ctx, p):  # noqa: ARG001 - the Candidate contract
        bmax = ctx.settings.discover_beta_max
        if "beta" in p and not (-bmax <= float(p["beta"]) <= bmax):
            return f"speed exponent {float(p['beta']):.2f} outside [-{bmax:g}, {bmax:g}]"
        ratio = ctx.settings.discover_size_ratio_max
        if d0 is not None and not (d0 / ratio <= float(p["decay_s"]) <= d0 * ratio):
            return f"decay time {float(p['decay_s']):.3g} s far from the discovered {d0:.3g} s"
        amp = math.sqrt(
            float(jnp.mean(jnp.asarray(p["cos_rad"]) ** 2))
            + float(jnp.mean(jnp.asarray(p.get("sin_rad", 0.0)) ** 2))
        )
        if amp0 > 0 and not (amp0 / ratio <= amp <= amp0 * ratio):
            return f"amplitude {amp:.3g} {unit} far from the discovered {amp0:.3g} {unit}"
        return None

    sig = (
        ("time", "drift", "direction", "speed", "run_step")
        if offset
        else ("spectrum", "orders", "common_orders", "modulated_orders", "common_modulated")
    )
    return Candidate(
        name=name,
        fn=fn,
        params=tuple(params),
        signature=sig,
        kinds=(spec["export"]["kind"],),
        explanation="Discovered outside the catalog by an earlier diagnosis: " + spec["reading"],
        start=start,
        plausible=plausible,
    )


def export_candidates(doc: Mapping[str, Any], path: str | Path) -> list[str]:
    """Write the discovered terms of a diagnosis document as a ``--candidates`` module;
    returns the candidates' names (empty: nothing discovered, no file written)."""
    specs: dict[str, dict] = {}
    for u in doc.get("unexplained", ()):
        for t in (u.get("model") or {}).get("terms", ()):
            specs.setdefault(candidate_name(t), t)
    if not specs:
        return []
    body = json.dumps(list(specs.values()), indent=1)
    text = (
        f'"""Candidates discovered by encdesign diagnose in {doc.get("recording")!s}: pass this\n'
        'file to `encdesign diagnose REC --candidates FILE` (issue 41)."""\n\n'
        "import json\n\n"
        "from encdesign.diagnose import discovered_candidate\n\n"
        f"SPECS = json.loads(r'''{body}''')\n\n"
        "CANDIDATES = [discovered_candidate(s) for s in SPECS]\n"
    )
    atomic_write_text(Path(path), text)
    return list(specs)
