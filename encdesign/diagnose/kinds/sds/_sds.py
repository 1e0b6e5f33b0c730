"""``sds`` kind of the discrepancy-finder engine (edge times of a shifted-delta-sum bench).

Data (:func:`sds_pair_table`): every run (one platform position φ_r) and every complete
revolution gives one shifted delta sum per fixed × moving sensor pair (seed 001 eqs. 23–24,
pair constants from the nominal sensor azimuths of the TOML), with the mean time of each
sensor's window. The engine sees **one row per run** and, per moving sensor ``m``, ``K``
channels: the run mean over the ``K`` revolutions (channel ``m<i>``, the pair values averaged
over the fixed sensors, minus ``φ_ref``) and ``K − 1`` orthonormal (Helmert) contrasts over the
revolutions (channels ``m<i>.d<k>``), so that the two noise levels of an SDS bench (run to
run, e.g. clock ticks locked to the revolution, and revolution to revolution) are separate
channels with their own noise, and rows (runs) are independent. Every term is computed per
pair and revolution and mapped the same way, so it stays one differentiable function.

Base model (what the design includes), per pair (f, m), with ``x = φ_r + ψ_m``:

    y = c_m + Σ_{n ∈ design orders} a_n cos n x + b_n sin n x

the pair constants averaged over the fixed sensors ``c_m`` and the product of the design's
speed ripple with disk B's mark errors at the design motor's orders (multiples of
``pole_pairs``, of ``pole_pairs·commutation_states`` and the cogging order, up to
``R·M/2 − 1``; seed 001 eqs. 46–53). Without ``phi_ref`` the datum is ``wrap(SDS − φ̂_r)``
with φ̂_r the run's mean reading, and every term is projected on the differences between the
moving sensors of a run (the per-run offset is a nuisance that takes everything common to
the moving sensors): the absolute angle per run, the common constant, what is common to the
moving sensors (beam tilt × axial runout, coil orders at multiples of M, a common drift
across runs) are unidentifiable and listed.

Candidates (``docs/effects.md``, "SDS timing model"), each a differentiable term:

* ``axis_tilt``: ``T(φ+ψ_m) − T(ψ_f)``, ``T(ψ) = atan2(sin(ψ−χ), cos(ψ−χ) cos β) − (ψ−χ)``
  (seed eq. 26), parameters β (rad), χ (rad); χ is unidentifiable when β is not resolved;
* ``thermal_drift``: ``k (max(t_m − t_on, 0) − max(t̄ − t_on, 0))`` (no temperature column
  in sds: time drives; a drift from an onset ``t_on``, fitted, or from the start,
  ``k (t_m − t̄)``: :mod:`._sds_drift`);
* ``bearing_wobble``: ``w(t_m, φ+ψ_m) − w(t_f, ψ_f)``,
  ``w = sinc(ρ) [A sin(ρΩt − ψ) + B cos(ρΩt − ψ)]`` (window mean over one revolution);
* ``beam_tilt_axial``: ``Σ_{n=1..3} p_n cos nφ + q_n sin nφ`` common to the moving sensors;
* ``coil_mismatch``: Fourier terms in ``x`` at the coil orders ``1 … pole_pairs − 1`` (less
  those with one phase at every moving sensor without phi_ref,
  :func:`~encdesign.diagnose.kinds.sds._sds_noise.coil_orders`), the lowest as many as the
  parameter budget leaves (:func:`~encdesign.diagnose.kinds.sds._sds_terms.coil_order_count`);
* ``sensor_delay_step``: one moving sensor's edges delayed by ``τ_m`` from one run on
  (electronics, cable, a re-plugged connector): ``+Ω τ_m`` on that sensor's pairs;
* ``timing_quantization``: the time stamps lie on a lattice coarser than the declared clock
  (:func:`stamp_lattice`, found from the data for any clock); a noise floor, named from the
  lattice, not fitted.

Views: the engine's ``orders`` (per channel, in φ), a run-step view (per moving sensor, the
best change point over the runs in time order, and single-run outliers) and one matched
view per candidate (the power its columns take out of the whitened residual).
"""

from __future__ import annotations

import math
from typing import ClassVar, final

import jax.numpy as jnp
import numpy as np

from ...engine._fit import valjac_fn as _valjac_fn
from ...engine._kind import AbstractKind
from ...engine._located import change_chi2, interval_of, located_time
from ...engine._padded import eval_rows
from ...engine._protocol import KindView, Prepared
from ...engine._settings import DEFAULT_SETTINGS, FinderSettings
from ...engine._views import Finding
from ...engine._views import chi2_threshold as _thr
from ...engine._views import log10_tail_p as _logp
from ...engine._views import make_where as _where
from ._sds_common_mod import view_common_modulated, view_common_orders
from ._sds_common_rules import rounding_scale
from ._sds_data import (
    SDSPairTable,
    lattice_floor,
    sds_data,
    sds_pair_table,
    sds_prepare,
    sds_speed_harmonics,
    stamp_lattice,
)
from ._sds_level_out import (
    LevelOut,
    modulated_scale,
    orders_scale,
    run_step_scale,
)
from ._sds_noise import (
    EXPLANATIONS,
    REFERENCE_RADIUS_M,
    _ls_power_flat,
    base_orders,
    noise_info,
    sds_noise,
)
from ._sds_probes import with_probes
from ._sds_terms import (
    _const_term,
    _ripple_term,
    _wobble_grid,
    _wobble_onsets,
    moving_opposed,
    sds_candidates,
)

__all__ = [
    "SDS",
    "SDSPairTable",
    "sds_pair_table",
    "sds_speed_harmonics",
    "stamp_lattice",
]

# ----------------------------------------------------------------------------- views


def view_run_step(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """Per moving sensor (run-mean channels), the best step over the runs in time order and
    the strongest single-run outlier; 1 dof each, Bonferroni over sensors x positions."""
    M = prep.consts["psi_m"].size
    r = rw[:, :M]
    R = r.shape[0]
    n_tests = max(1, 2 * M * (R - 1))
    thr = _thr(prep.settings.alpha, 1, n_tests)
    c_change = change_chi2(prep.settings.change_time_level)
    f_step, f_out = np.ones((M, R)), np.ones((M, R))
    level = _level_and_angle(prep)
    if level is not None and level[0].share and np.asarray(prep.keep).size == R:
        f_step, f_out = run_step_scale(level[0], np.asarray(prep.keep, bool), M)
    out = []
    for m in range(M):
        x = r[:, m] - r[:, m].mean()
        best = (0.0, 1, "step")
        prof = np.zeros(R)  # chi-square a step from run k on takes out (its profile)
        for k in range(1, R):
            s = (np.arange(R) >= k).astype(float)
            s -= s.mean()
            pw = float((s @ x) ** 2 / (s @ s)) * float(f_step[m, k])
            prof[k] = pw
            if pw > best[0]:
                best = (pw, k, "step")
        p_out = x**2 * R / (R - 1) * f_out[m]  # at the level without itself (its share)
        j = int(np.argmax(p_out))
        pw_out = float(p_out[j])
        if pw_out > best[0]:
            best = (pw_out, j, "run_outlier")
        if best[0] > thr:
            k = best[1]
            located = None
            if best[2] == "step":  # issue 44 C: the runs within the profile's bound
                ks = np.arange(1, R)
                _, lo, hi = interval_of(ks, -prof[1:], c_change, best=k)
                located = located_time(prep, np.arange(R), k, lo, hi)
            out.append(
                Finding(
                    "run_step",
                    _where(
                        heads=[m],
                        runs=[int(prep.run_ids[k])],
                        times_s=[float(prep.rows["t"][k])],
                    ),
                    best[0],
                    1,
                    _logp(best[0], 1),
                    detail={
                        "shape": best[2],
                        "first_run_index": int(k),
                        "sensor": f"m{m}",
                        "n_values": int(R),
                    },
                    located_time=located,
                )
            )
    return out


def _matched_view(name: str):
    """A view: the power the candidate's columns (at its start) take out of the residual."""

    def view(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
        ctx = prep.ctx
        cands = {c.name: c for c in sds_candidates(ctx)}
        if name not in cands:
            return []
        cand = cands[name]
        if cand.applies is not None and cand.applies(ctx):
            return []
        consts = {k: v for k, v in ctx.consts.items() if isinstance(v, np.ndarray)}
        M = int(np.asarray(ctx.consts["psi_m"]).size)
        resid = rw * prep.sigma[None, :]
        starts = cand.start(ctx, resid, []) if cand.start else [{}]
        best = (0.0, 0)
        for st in starts:
            p = {}
            for q in cand.params:
                shp = q.resolved_shape(ctx.n_channels, ctx.n_runs)
                v0 = st.get(q.name)
                p[q.name] = jnp.asarray(np.zeros(shp) if v0 is None else v0, float)
            free = [q.name for q in cand.params if q.fit]
            _, J = eval_rows(_valjac_fn(cand), p, ctx.rows, consts)  # bucketed lengths
            cols = (
                np.concatenate([np.asarray(J[k]).reshape(*rw.shape, -1) for k in free], axis=-1)
                / prep.sigma[None, :, None]
            )
            pw = _ls_power_flat(rw, cols) * rounding_scale(ctx, cols, M)
            q_eff = int(np.linalg.matrix_rank(cols.reshape(-1, cols.shape[-1]), tol=None))
            if pw > best[0]:
                best = (pw, max(q_eff, 1))
        pw, q = best
        n_starts = (
            len(_wobble_grid(ctx)) * len(_wobble_onsets(int(ctx.n_runs)))
            if name == "bearing_wobble"
            else max(len(starts), 1)
        )
        thr = _thr(prep.settings.alpha, q, 6 * n_starts)
        if pw <= thr:
            return []
        return [
            Finding(
                f"sds_{name}",
                _where(heads=list(range(prep.n_channels)), runs=prep.run_ids.tolist()),
                pw,
                q,
                _logp(pw, q),
                detail={"n_values": int(rw.size), "candidate": name},
            )
        ]

    return view


def view_mean_orders(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """The engine's ``orders`` view on the run-mean channels only (a pattern in the platform
    angle is constant within a run: it cannot reach the revolution contrasts, whose
    scan would only add false alarms). Each order on each sensor is read against the
    run-mean level without its own columns (:mod:`._sds_level_out`, issue 41 session 23)."""
    from ...engine._views import view_orders

    M = prep.consts["psi_m"].size
    top = min(scan_order, sds_limit(prep))
    level = _level_and_angle(prep)
    scale = None
    if level is not None:
        scale = orders_scale(*level, M, top, rw.shape[1])
    return view_orders(prep, rw, top, list(range(M)), scale)


def _level_and_angle(prep: Prepared) -> tuple[LevelOut, np.ndarray] | None:
    """The run-mean level's factor (:class:`._sds_level_out.LevelOut`) and the platform
    angle (rad) on the kept rows it is read on; ``None`` where the kind's noise has no
    factor."""
    factor = noise_info(prep.ctx).level_factor
    if factor is None:
        return None
    name = "theta_eff" if "theta_eff" in prep.rows else "theta"
    return factor, np.asarray(prep.rows[name], float)[prep.keep]


def view_mean_modulated(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """The engine's ``modulated_orders`` view (an order that grows or switches over the
    runs) on the run-mean channels, orders as :func:`view_mean_orders` scans them; an order
    that view reports is reported here too where its shape is the stronger evidence
    (``beside_static``: the 24 golden-angle positions make a switching order's
    near-aliases outrank it otherwise)."""
    from ...engine._views_modulated import scan_modulated

    M = prep.consts["psi_m"].size
    top = min(scan_order, sds_limit(prep))
    level = _level_and_angle(prep)
    scale = None
    if level is not None:
        factor, th = level
        C = rw.shape[1]

        def scale(kidx, edges):
            return (
                modulated_scale(factor, th, _mean_shapes(prep, kidx, edges), M, top, C),
                orders_scale(factor, th, M, top, C),
            )

    return scan_modulated(prep, rw, top, list(range(M)), M, beside_static=True, scale=scale)


def _mean_shapes(prep: Prepared, kidx: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``(2 + 2K, kept runs)``: the ``modulated_orders`` view's amplitude shapes (growth,
    decay, then switch on / off at each edge of the kept rows ``kidx`` in time order), each
    on the kept run means in the level's order (``prep.keep``)."""
    n = kidx.size
    j = np.arange(n)
    g = j / max(n - 1, 1)
    rows = [g, 1.0 - g]
    for e in edges:
        on = (j >= e).astype(float)
        rows += [on, 1.0 - on]
    out = np.zeros((len(rows), np.asarray(prep.keep).size))
    out[:, kidx] = np.stack(rows)
    return out[:, np.asarray(prep.keep, bool)]


# the run-step view first: findings are ranked by p-value, which floors at 1e-999 for a
# strong structure; among equals the most specific location (one sensor, one run) leads
SDS_VIEWS = (
    KindView(view_run_step, ("run_step",)),
    KindView(view_mean_orders, ("orders",)),
    KindView(view_mean_modulated, ("modulated_orders",)),
    KindView(view_common_orders, ("common_orders",)),
    KindView(view_common_modulated, ("common_modulated",)),
    *(
        KindView(_matched_view(n), (f"sds_{n}",))
        for n in (
            "axis_tilt",
            "thermal_drift",
            "bearing_wobble",
            "beam_tilt_axial",
            "coil_mismatch",
        )
    ),
)


# ----------------------------------------------------------------------------- base


def sds_limit(prep: Prepared) -> int:
    """Highest order in ``x = φ + ψ_m`` the record resolves: ``R·M/2 − 1``."""
    M = prep.consts["psi_m"].size
    return int(max(1, prep.ctx.n_runs * M // 2 - 1))


def sds_base(prep: Prepared, max_order: int):
    """Pair constants plus the design's ripple orders (see module doc)."""
    enc = prep.ctx.meta.get("encoder", {})
    M = prep.consts["psi_m"].size
    p = int(enc.get("pole_pairs", 0) or 0)
    terms = [(_const_term(M), {})]
    # without phi_ref an order with one phase at every moving sensor is taken by the
    # per-run offset: its projected columns are zero up to rounding, which a normalised
    # solve would fit as if they carried information; left out and listed (common_x)
    orders, common_x = base_orders(prep.ctx.meta, prep.consts, max_order)
    if orders:
        terms.append((_ripple_term(tuple(orders)), {}))
    has_ref = prep.ctx.has_ref
    unid = [
        "the constant offset (instrument zero): its physical causes cannot be told apart",
    ]
    if not has_ref:
        unid += [
            "no phi_ref: the absolute platform angle of each run (a per-run offset is "
            "taken out), so the common constant of the moving sensors is held",
            "no phi_ref: anything common to the moving sensors of a run (beam tilt x axial "
            f"runout, orders that are multiples of {M} in x, a common drift across runs)",
        ]
        common = [n for n in range(1, p) if n % M == 0 and M > 1]
        if common:
            unid.append(
                f"no phi_ref: coil_mismatch orders {common} have one phase at every moving "
                "sensor (multiples of the moving-sensor count): held as unidentifiable"
            )
    if common_x:
        unid.append(
            f"no phi_ref: design orders {common_x} have one phase at every moving sensor "
            "(taken by the per-run offset): left out of the base model"
        )
    info = {
        "design_orders": orders,
        "pole_pairs": p,
        "n_revolutions_per_run": int(prep.kd.n_revs),
        "revolutions_left_out": int(prep.kd.dropped_revs),
        "radius_m": float(prep.kd.radius_m or REFERENCE_RADIUS_M),
        "unidentifiable": unid,
    }
    return terms, info


def sds_summary(prep: Prepared, base_params: dict) -> dict:
    """The clock block: the stamp lattice found in the data against the declared clock."""
    kd = prep.kd
    lat = dict(kd.lattice or {})
    P = lat.get("period_s")
    ratio, floor = lattice_floor(kd)
    return {
        "clock": {
            "declared_period_s": kd.declared_clock_s,
            "lattice_period_s": P,
            "ratio_to_declared": ratio,
            "fraction_on_lattice": lat.get("fraction_on_lattice"),
            "predicted_floor_rad": floor,
            "method": lat.get("method"),
        },
        "grid_period_s": P,
        "noise_estimate": dict(noise_info(prep.ctx).levels),
        "moving_opposed": moving_opposed(prep.consts["psi_m"]),
        "drift_vs_orders": noise_info(prep.ctx).drift_vs_orders,
    }


@final
class SDSKind(AbstractKind):
    """``sds``: the shifted-delta-sum timing instrument, one row per run."""

    name: ClassVar[str] = "sds"
    default_max_order: ClassVar[int] = 60
    noise_replaces: ClassVar[bool] = True
    grows_orders: ClassVar[bool] = False
    reading_lattice: ClassVar[bool] = False

    def data(self, rec, settings=DEFAULT_SETTINGS):
        return sds_data(rec, settings)

    def views(self, prep):
        return SDS_VIEWS

    def plots(self, d, folder):
        return []

    def base(self, prep, max_order):
        return sds_base(prep, max_order)

    def candidates(self, ctx):
        return with_probes(sds_candidates(ctx))

    def max_order_limit(self, prep):
        return sds_limit(prep)

    def prepare(self, kd, meta, settings):
        return sds_prepare(kd, meta, settings)

    def noise(self, prep, base_resid):
        return sds_noise(prep, base_resid)

    def refine(self, terms, prep):
        return None

    def align(self, terms, prep):
        return None

    def summary(self, prep, base_params):
        return sds_summary(prep, base_params)

    def finish(self, prep, doc, settings):
        return finish_sds(doc, settings)

    def report_lines(self, doc):
        return ""


SDS = SDSKind()


# ----------------------------------------------------------------------------- finish


NOISE_METHOD = (
    "run means: residual of a saturated least-squares fit of the base residual (smooth "
    "patterns in the platform angle, drift, significant change points and single-value "
    "outliers), sqrt(SSR / dof) with dof = independent values - rank (R(M-1) values without "
    "phi_ref), widened by sqrt(q F(q, dof) / chi2(q)) at p = 1e-4 for its estimation error "
    "(estimate, dof and factor under 'estimate'), with phi_ref raised for the noise common to "
    "the moving sensors (run_means_common_factor: the contrasts' and the fixed sensors' "
    "excess); revolution contrasts: 1.4826 MAD, the larger "
    "of the parts common to the moving sensors and their differences"
)


def finish_sds(doc: dict, settings: FinderSettings = DEFAULT_SETTINGS) -> dict:
    """SDS additions to the engine's document: ``timing_quantization`` named from the stamp
    lattice (a floor, not a fitted term), the quantization floor in the goodness of fit,
    honest standard errors (scaled by the final variance ratio when it exceeds 1; the
    azimuth of an unresolved tilt is unidentifiable), and no non-finite number anywhere."""
    clock = doc.get("clock", {})
    est = doc.pop("noise_estimate", None)
    if isinstance(doc.get("noise"), dict):
        doc["noise"]["method"] = NOISE_METHOD
        if est:
            doc["noise"]["estimate"] = est
    gof = doc.get("goodness_of_fit") or {}
    vr = float(gof.get("variance_ratio", 1.0) or 1.0)
    scale = math.sqrt(max(vr, 1.0))
    noise = doc.get("noise", {}).get("per_channel", [])
    floor = clock.get("predicted_floor_rad")
    if isinstance(gof, dict):
        gof["quantization"] = {
            "lattice_period_s": clock.get("lattice_period_s"),
            "predicted_floor_rad": floor,
            "noise_run_means_rad": noise[0] if noise else None,
            "note": "the noise levels are estimated from the data and so include the "
            "quantization of the stamps on the lattice found; the predicted floor "
            "2 pi P / (T sqrt(6 N)) is what a perfect bench on that lattice would show",
        }
    dv = doc.pop("drift_vs_orders", None)
    if doc.pop("moving_opposed", False):
        _tilt_beam_opposed(doc, settings)
    _tilt_coil_pair(doc, settings)
    for e in doc.get("effects", []):
        if e["name"] == "thermal_drift" and dv:
            lim = math.log(max(dv["n_values"], 2))
            # a drift with an onset in the record: its power at the best onset, 2 dof
            onset = not e.get("derived", {}).get("drift_from_start", {}).get("value", True)
            pd, kd = (dv["onset_power"], 2) if onset else (dv["drift_power"], 1)
            if dv["order_power"] >= pd - lim:
                # within one parameter's worth: the data cannot tell the two apart
                e["confounded_with"] = [
                    *(e.get("confounded_with") or []),
                    {
                        "name": f"platform_angle_order_{dv['order']}",
                        "reason": f"order {dv['order']} of the platform angle, common to the "
                        f"moving sensors, fits the base residual nearly as well (chi-square "
                        f"{dv['order_power']:.1f}, 2 dof, vs the drift's "
                        f"{pd:.1f}, {kd} dof; correlation "
                        f"{dv['correlation']:.2f}): with this platform stepping it is nearly "
                        "a trend over the runs",
                        "rule": "one_parameter_bic",
                        "delta_bic": None,
                        "params": {},
                    },
                ]
                e["notes"] = [
                    *e.get("notes", []),
                    f"confounded with order {dv['order']} of the platform angle (out of "
                    "catalog): this recording cannot tell a drift in time from it; step the "
                    "platform in another order or repeat positions to separate them",
                ]
        for q in e.get("params", {}).values():
            if isinstance(q.get("se"), list | float | int) and scale > 1:
                q["se"] = _scale(q["se"], scale)
        on = e.get("derived", {}).get("onset_s")
        if e["name"] == "thermal_drift" and on is not None and on.get("se") is not None:
            on["se"] = e["params"]["onset_from_start_s"]["se"]  # the same, scaled as it is
        if e["name"] == "axis_tilt":
            p = e["params"]
            # (tilt, azimuth) and (-tilt, azimuth + pi) are one tilt: report tilt >= 0 and
            # the azimuth in [0, pi)
            if p["tilt_rad"]["value"] < 0:
                p["tilt_rad"]["value"] = -p["tilt_rad"]["value"]
            p["azimuth_rad"]["value"] = float(np.mod(p["azimuth_rad"]["value"], np.pi))
            b, sb = abs(p["tilt_rad"]["value"]), p["tilt_rad"]["se"]
            if sb is None or not b > settings.resolved_se * sb:
                p["azimuth_rad"]["se"] = None
                e["notes"] = [
                    *e.get("notes", []),
                    f"the tilt is not resolved (|tilt| <= {settings.resolved_se:g} se): its "
                    "azimuth is unidentifiable",
                ]
    ratio = clock.get("ratio_to_declared")
    if ratio is not None and ratio > settings.sds_lattice_coarser:
        rms = doc.get("rms_final", doc.get("rms_before"))
        doc["effects"].append(
            {
                "name": "timing_quantization",
                "params": {
                    "clock_period_s": {
                        "value": clock["lattice_period_s"],
                        "se": None,
                        "unit": "s",
                    },
                    "declared_period_s": {
                        "value": clock["declared_period_s"],
                        "se": None,
                        "unit": "s",
                    },
                    "predicted_floor_rad": {"value": floor, "se": None, "unit": "rad"},
                },
                "derived": {},
                "channels": None,
                "rms_after": rms,
                "heldout_rms_after": doc.get("heldout_rms_final"),
                "delta_bic": None,
                "collinearity": None,
                "share": 0.0,
                "notes": [
                    f"every stamp lies on a {clock['lattice_period_s']:.4g} s lattice, "
                    f"{ratio:.3g} x the declared clock period; named from the lattice, not "
                    "fitted (a noise floor): delta_bic and collinearity do not apply"
                ],
                "explanation": EXPLANATIONS["timing_quantization"],
            }
        )
    elif clock.get("lattice_period_s") is None and clock.get("declared_period_s"):
        doc["notes"].append(
            "no stamp lattice found in the data although a clock is declared: the stamps "
            "look continuous (interpolated or free-running time)"
        )
    return _finite(doc)


TILT_BEAM_SEPARATE_BY = (
    "a moving sensor not opposed to the others (e.g. three at 120 degrees): the tilt's "
    "order 2 then has a different phase at each moving sensor, beam tilt x axial runout "
    "stays common to them"
)


def _tilt_beam_opposed(doc: dict, settings: FinderSettings = DEFAULT_SETTINGS) -> None:
    """With the moving sensors opposed (one azimuth modulo π), ``axis_tilt`` (order 2 in
    ``φ + ψ_m``, π-periodic) is the same at every moving sensor, as ``beam_tilt_axial`` at
    order 2 of ``φ`` is: where the engine reports the two as confounded, say why and which
    layout separates them (not the generic "other speeds" of a multihead bench).

    The engine's tie rule compares the two whole fits; beam tilt's orders 1 and 3 then take
    some noise, and its fitted error can correlate below ``tie_corr`` with the tilt's
    although the tilt's is exactly beam tilt's at order 2 (both: one amplitude and one
    phase of order 2 in φ common to the moving sensors; the tilt's part at the fixed
    sensors is a constant, taken by the pair constants). So, on this layout: a named
    ``axis_tilt`` is always confounded with a tried ``beam_tilt_axial`` (axial runout at
    order 2 alone gives the same record); a named ``beam_tilt_axial`` is confounded with a
    tried ``axis_tilt`` when its orders 1 and 3 do not lower the criterion by
    ``tie_chi2`` more than the tilt does (the record does not support them)."""
    pair = {"axis_tilt", "beam_tilt_axial"}
    _opposed_pair_from_refusals(doc, settings)
    for e in doc.get("effects", []):
        if e["name"] not in pair:
            continue
        other = (pair - {e["name"]}).pop()
        hit = [c for c in e.get("confounded_with") or [] if c.get("name") == other]
        for c in hit:
            c["separate_by"] = TILT_BEAM_SEPARATE_BY
        if hit:
            e["notes"] = [
                *e.get("notes", []),
                f"confounded with {other}: with the moving sensors opposed, the tilt's error "
                "(repeating every half turn) is the same at each of them, as beam tilt x "
                "axial runout at order 2 of the platform angle is; the fitted values are "
                f"those of {e['name']} alone. Separated by {TILT_BEAM_SEPARATE_BY}",
            ]
    for c in doc.get("confounded", []):
        if set(c.get("pair", [])) == pair:
            c["separate_by"] = TILT_BEAM_SEPARATE_BY


def _refused_partners(doc: dict, pair: tuple[str, str]):
    """``(named, other, refusal, other's dBIC, named's dBIC)`` for each named effect of
    ``pair`` whose partner was tried and refused only because the named one lowers the
    criterion more (rule ``better_candidate``), not already its ``confounded_with``."""
    for e in doc.get("effects", []):
        if e["name"] not in pair:
            continue
        other = pair[1 - pair.index(e["name"])]
        if any(c.get("name") == other for c in e.get("confounded_with") or []):
            continue
        rej = next((r for r in doc.get("rejected", []) if r["name"] == other), None)
        if rej is None or rej.get("rule") != "better_candidate":
            continue
        db, db0 = rej.get("delta_bic"), e.get("delta_bic")
        if db is not None and db0 is not None:
            yield e, other, rej, db, db0


def _record_pair(doc: dict, e: dict, other: str, rej: dict, why: str, separate_by: str) -> None:
    """The refused partner ``other`` as the named ``e``'s ``confounded_with`` entry (its
    refusal removed) and one ``confounded`` pair of the two, rule ``tie_chi2``."""
    db, db0 = float(rej["delta_bic"]), float(e["delta_bic"])
    entry = {"name": other, "reason": why, "rule": "tie_chi2", "delta_bic": db, "params": {}}
    entry.update(correlation=1.0, separate_by=separate_by)
    e["confounded_with"] = [*(e.get("confounded_with") or []), entry]
    doc["rejected"].remove(rej)
    doc.setdefault("confounded", []).append(
        {
            "pair": [e["name"], other],
            "correlation": 1.0,
            "delta_bic": db - db0,
            "separate_by": separate_by,
            "reason": why + f"; {e['name']} is named",
            "rule": "tie_chi2",
        }
    )


def _opposed_pair_from_refusals(doc: dict, settings: FinderSettings) -> None:
    """A tried partner of the tilt / beam-tilt pair refused only because the named one
    lowers the criterion more becomes the named one's ``confounded_with`` entry and one
    ``confounded`` pair (see :func:`_tilt_beam_opposed`)."""
    for e, other, rej, db, db0 in _refused_partners(doc, ("axis_tilt", "beam_tilt_axial")):
        if e["name"] == "beam_tilt_axial" and not db - db0 < settings.tie_chi2:
            continue  # its orders 1 and 3 are supported: told apart by the criterion
        why = (
            "with the moving sensors opposed the tilt's error is beam tilt x axial runout at "
            "order 2 of the platform angle (one amplitude and one phase common to the moving "
            f"sensors, the same columns); {e['name']} lowers the criterion by {db - db0:.1f} "
            f"more (needs "
            f"{settings.tie_chi2:.0f} to decide"
            + (
                ": beam tilt's orders 1 and 3 are not supported by the record)"
                if e["name"] == "beam_tilt_axial"
                else "; beam tilt's orders 1 and 3 only add parameters)"
            )
        )
        _record_pair(doc, e, other, rej, why, TILT_BEAM_SEPARATE_BY)


TILT_COIL_SEPARATE_BY = (
    "the shaft speed ripple at order 2 (a coil mismatch moves the speed, which the moving "
    "sensors' edge intervals show: speed_ripple_relative_order_2; an axis tilt does not), "
    "or the axis aligned by a separate measurement"
)


def _tilt_coil_pair(doc: dict, settings: FinderSettings = DEFAULT_SETTINGS) -> None:
    """``axis_tilt`` (order 2 in ``φ + ψ_m``; its part at the fixed sensors a constant,
    taken by the pair constants) lies in the columns of ``coil_mismatch`` where the coil
    fits order 2 (Fourier terms in ``φ + ψ_m``): a tilt and a coil's order 2 give the same
    record. The engine's tie rule compares the two whole fits: with a coil's order 1 (or
    3 …) in the record beside a tilt, the coil lowers the criterion by more than
    ``tie_chi2`` beyond the tilt, the tilt is refused as the worse candidate and then adds
    nothing to the coil: one name, silently (a 10x tilt beside a 1.5x coil named only the
    coil). So a named ``coil_mismatch`` that fits order 2 is confounded with a tried
    ``axis_tilt`` refused only because the coil lowers the criterion more (its order-2
    part may be the tilt); a named ``axis_tilt`` is confounded with a tried
    ``coil_mismatch`` so refused when the coil's other orders do not lower the criterion
    by ``tie_chi2`` more than the tilt does (the record does not support them). Each such
    pair is the named one's ``confounded_with`` entry and one ``confounded`` pair."""
    for e, other, rej, db, db0 in _refused_partners(doc, ("axis_tilt", "coil_mismatch")):
        coil = e if e["name"] == "coil_mismatch" else None
        if coil is not None and "order_2_amplitude_rad" not in (coil.get("derived") or {}):
            continue  # the coil fits order 1 alone: the tilt is not in its columns
        if coil is None and not db - db0 < settings.tie_chi2:
            continue  # the coil's other orders are supported: told apart by the criterion
        speed = ((coil or {}).get("derived") or {}).get("speed_ripple_relative_order_2")
        why = (
            "an axis tilt's error is order 2 of phi + psi_m (its part at the fixed sensors a "
            "constant), the coil's order 2 the same columns; "
            f"{e['name']} lowers the criterion by {db - db0:.1f} more (needs "
            f"{settings.tie_chi2:.0f} to decide"
            + (
                "; the fitted order 2 of the coil may be the tilt's)"
                if coil is not None
                else ": the coil's other orders are not supported by the record)"
            )
            + (
                f"; the shaft speed ripple at order 2 from the edge intervals: "
                f"{speed['value']:.3g} +- {speed['se']:.2g} (relative)"
                if speed and speed.get("se") is not None
                else ""
            )
        )
        e["notes"] = [
            *e.get("notes", []),
            f"confounded with {other} (order 2 of phi + psi_m): the fitted values are those "
            f"of {e['name']} alone. Separated by {TILT_COIL_SEPARATE_BY}",
        ]
        _record_pair(doc, e, other, rej, why, TILT_COIL_SEPARATE_BY)


def _scale(v, s):
    if isinstance(v, list):
        return [_scale(x, s) for x in v]
    return None if v is None else float(v) * s


def _finite(v):
    """Non-finite numbers become ``None`` (the JSON has no NaN)."""
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_finite(x) for x in v]
    if isinstance(v, float | np.floating) and not math.isfinite(float(v)):
        return None
    return v
