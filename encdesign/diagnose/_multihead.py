"""Discrepancy finder: fit the base model to a recording, locate the mismatch, name the
missing physics from the catalog, fit it, and show the fit improve on held-out data.

Multihead kind. The base model (``docs/effects.md``) per head ``k`` at azimuth ``alpha_k``::

    reading_k = theta + c_k + sum_{m=1..M} a_m cos m(theta - alpha_k - d_k) + b_m sin m(...)

one disk error function seen through every head (eccentricity is order 1 with amplitude
``e/R``, tilt mostly order 2, grating errors any order, head placement errors ``d_k``) plus
white noise. With ``theta_ref`` the residual is ``reading - theta_ref - model``. Without it
the shaft angle is unknown at every sample: minimising over it removes the head mean of the
residual at each sample, so only head differences are fitted (Cramer's self-compensation
setting, seed 000 sections III-IV); then the head constants' common part, all common-mode
effects, and every order ``m`` whose head pattern ``exp(-i m alpha_k)`` is the same for all
heads (multiples of the head symmetry) are unidentifiable and are reported as such.

Candidate effects (``encdesign.diagnose._effects``) are added one at a time and fitted with
optimistix Levenberg-Marquardt (one compiled solver for every fit of a recording shape:
the active parameters are gathered by index). A candidate is named only if it lowers the
information criterion (BIC with the noise variance known), lowers the residual on held-out
revolutions (two folds: even and odd revolutions of every run), and leaves no significant
structure at the place that motivated it; otherwise the structure is reported as
``unexplained`` with its location.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from .._errors import input_error
from ..io._recording import Recording, load_recording
from . import _effects as fx
from ._locate import (
    Finding,
    LocateInput,
    finding_power,
    line_phase_runs,
    locate,
    noise_sigma,
)

VERDICTS = ("consistent", "missing_physics", "unexplained")

# ----------------------------------------------------------------------------- layout


@dataclasses.dataclass(frozen=True)
class Layout:
    """Static shape of the parameter vector (hashable: one compiled solver per layout).

    Attributes:
        n_heads, max_order, n_runs, runout_orders, grating_lines: sizes.
        has_ref: whether ``theta_ref`` is fitted against.
        n_active: length of the gathered (active) parameter vector (the largest of the
            sizes in ``active_sizes``).
        active_sizes: the gathered lengths compiled for (smallest that fits is used).
    """

    n_heads: int
    max_order: int
    n_runs: int
    runout_orders: int
    grating_lines: int
    has_ref: bool
    n_active: int
    active_sizes: tuple[int, ...] = ()

    @property
    def segments(self) -> dict[str, tuple[int, int]]:
        """name -> (start, size)."""
        H, M, R, Mz = self.n_heads, self.max_order, self.n_runs, self.runout_orders
        sizes = [
            ("c", H),
            ("a", M),
            ("b", M),
            ("d", H),
            ("bt_beta", H),
            ("bt_zc", Mz),
            ("bt_zs", Mz),
            ("wb_nu", 1),
            ("wb_A", R),
            ("wb_B", R),
            ("vb_f", 1),
            ("vb_C", R * H),
            ("vb_S", R * H),
            ("th_k", H),
            ("ip", 4 * H),
            ("es_t", 1),
            ("es_x", 1),
            ("es_y", 1),
        ]
        out, s = {}, 0
        for name, n in sizes:
            out[name] = (s, n)
            s += n
        return out

    @property
    def size(self) -> int:
        """Number of parameters (a dummy slot follows at index ``size``)."""
        return sum(n for _, n in self.segments.values())


def _seg(p, layout: Layout, name: str):
    s, n = layout.segments[name]
    return p[s : s + n]


def _predict(p, data, layout: Layout):
    """Model (rad) ``(n, H)`` minus ``theta``: head constants + base + candidate terms."""
    H, R = layout.n_heads, layout.n_runs
    theta, alpha, radius = data["theta"], data["alpha"], data["radius_m"]
    out = _seg(p, layout, "c")[None, :] + fx.base_error_rad(
        theta, alpha, _seg(p, layout, "a"), _seg(p, layout, "b"), _seg(p, layout, "d")
    )
    orders = jnp.arange(1, layout.runout_orders + 1, dtype=theta.dtype)
    out = out + fx.beam_tilt_axial_rad(
        theta,
        radius,
        _seg(p, layout, "bt_beta"),
        _seg(p, layout, "bt_zc"),
        _seg(p, layout, "bt_zs"),
        orders,
    )
    oh = data["onehot"]
    out = out + fx.bearing_wobble_rad(
        theta,
        alpha,
        radius,
        _seg(p, layout, "wb_nu")[0],
        oh @ _seg(p, layout, "wb_A"),
        oh @ _seg(p, layout, "wb_B"),
    )
    out = out + fx.vibration_rad(
        data["t"],
        _seg(p, layout, "vb_f")[0],
        oh @ _seg(p, layout, "vb_C").reshape(R, H),
        oh @ _seg(p, layout, "vb_S").reshape(R, H),
    )
    out = out + fx.thermal_drift_rad(_seg(p, layout, "th_k"), data["driver"])
    if layout.grating_lines > 0:
        out = out + data["psi_mask"] * fx.interpolation_harmonics_rad(
            data["psi"], layout.grating_lines, _seg(p, layout, "ip").reshape(4, H)
        )
    out = out + fx.eccentricity_shift_rad(
        theta,
        data["tau"],
        alpha,
        radius,
        _seg(p, layout, "es_t")[0],
        _seg(p, layout, "es_x")[0],
        _seg(p, layout, "es_y")[0],
        data["width_s"],
    )
    return out


def _residual(p, data, layout: Layout):
    r = data["y"] - _predict(p, data, layout)
    if not layout.has_ref:
        r = r - jnp.mean(r, axis=1, keepdims=True)
    return r


def _model_jac(p, data, layout: Layout):
    """Analytic Jacobian of :func:`_predict`, shape ``(n, H, size)`` (segment order).

    Every term is linear in its amplitudes; the nonlinear parameters (placement ``d``,
    runout ``beta``/``z``, ``nu``, ``f``, ``t_s``) have closed-form derivatives. Checked
    against central finite differences in ``tests/test_diagnose.py``.
    """
    H, R, M, Mz = layout.n_heads, layout.n_runs, layout.max_order, layout.runout_orders
    theta, alpha, radius = data["theta"], data["alpha"], data["radius_m"]
    n = theta.shape[0]
    oh = data["onehot"]
    eye = jnp.eye(H, dtype=theta.dtype)
    blocks = []
    # c
    blocks.append(jnp.broadcast_to(eye[None], (n, H, H)))
    # a, b, d
    a, b, d = _seg(p, layout, "a"), _seg(p, layout, "b"), _seg(p, layout, "d")
    m = jnp.arange(1, M + 1, dtype=theta.dtype)
    arg = m[None, None, :] * (theta[:, None, None] - (alpha + d)[None, :, None])
    ca, sa = jnp.cos(arg), jnp.sin(arg)
    blocks += [ca, sa]
    de = -jnp.sum(m * (-a * sa + b * ca), axis=-1)  # d e_k / d d_k
    blocks.append(de[:, :, None] * eye[None])
    # beam tilt
    beta, zc, zs = _seg(p, layout, "bt_beta"), _seg(p, layout, "bt_zc"), _seg(p, layout, "bt_zs")
    mz = jnp.arange(1, Mz + 1, dtype=theta.dtype)
    cz, sz = jnp.cos(mz[None, :] * theta[:, None]), jnp.sin(mz[None, :] * theta[:, None])
    z = cz @ zc + sz @ zs
    blocks.append((z / radius)[:, None, None] * eye[None])
    blocks.append(cz[:, None, :] * (beta / radius)[None, :, None])
    blocks.append(sz[:, None, :] * (beta / radius)[None, :, None])
    # wobble
    nu = _seg(p, layout, "wb_nu")[0]
    A, B = oh @ _seg(p, layout, "wb_A"), oh @ _seg(p, layout, "wb_B")
    wa = nu * theta[:, None] - alpha[None, :]
    sw, cw = jnp.sin(wa), jnp.cos(wa)
    blocks.append((theta[:, None] * (A[:, None] * cw - B[:, None] * sw) / radius)[:, :, None])
    blocks.append(sw[:, :, None] * oh[:, None, :] / radius)
    blocks.append(cw[:, :, None] * oh[:, None, :] / radius)
    # vibration
    f = _seg(p, layout, "vb_f")[0]
    C = oh @ _seg(p, layout, "vb_C").reshape(R, H)
    S = oh @ _seg(p, layout, "vb_S").reshape(R, H)
    t = data["t"]
    w = 2.0 * jnp.pi * f * t
    cv, sv = jnp.cos(w), jnp.sin(w)
    blocks.append((2.0 * jnp.pi * t[:, None] * (-C * sv[:, None] + S * cv[:, None]))[:, :, None])
    rh = jnp.einsum("nr,kh->nkrh", oh, eye).reshape(n, H, R * H)
    blocks.append(rh * cv[:, None, None])
    blocks.append(rh * sv[:, None, None])
    # thermal
    blocks.append(data["driver"][:, None, None] * eye[None])
    # interpolation
    L = max(layout.grating_lines, 1)
    psi = data["psi"]
    if layout.grating_lines > 0:
        basis = jnp.stack(
            [jnp.cos(psi), jnp.sin(psi), jnp.cos(2 * psi), jnp.sin(2 * psi)], axis=1
        )  # (n, 4, H)
        blk = (basis[:, :, None, :] * eye[None, None]).reshape(n, 4 * H, H).transpose(0, 2, 1)
        blocks.append(blk * data["psi_mask"][:, :, None] / L)
    else:
        blocks.append(jnp.zeros((n, H, 4 * H), dtype=theta.dtype))
    # eccentricity shift
    ts, dx, dy = (_seg(p, layout, k)[0] for k in ("es_t", "es_x", "es_y"))
    width = data["width_s"]
    step = fx.smooth_step(data["tau"], ts, width)
    dstep = -step * (1.0 - step) / width
    dth = theta[:, None] - alpha[None, :]
    se, ce = jnp.sin(dth) / radius, jnp.cos(dth) / radius
    blocks.append((dstep[:, None] * (dx * se + dy * ce))[:, :, None])
    blocks.append((step[:, None] * se)[:, :, None])
    blocks.append((step[:, None] * ce)[:, :, None])
    return jnp.concatenate(blocks, axis=2)


def _resid_and_jac(z, p_full, scale, idx, data, w, layout: Layout):
    p = p_full.at[idx].add(scale[idx] * z)
    sw = jnp.sqrt(w)[:, None]
    r = _residual(p, data, layout) * sw
    Jm = jnp.take(_model_jac(p, data, layout), idx, axis=2, mode="fill", fill_value=0.0)
    Jm = Jm * (scale[idx] * (idx < layout.size))[None, None, :]
    J = -Jm
    if not layout.has_ref:
        J = J - jnp.mean(J, axis=1, keepdims=True)
    J = J * sw[:, :, None]
    return r.ravel(), J.reshape(-1, idx.shape[0])


def _make_fn(layout: Layout):
    @jax.custom_jvp
    def fn(z, args):
        p_full, scale, idx, data, w = args
        p = p_full.at[idx].add(scale[idx] * z)
        return (_residual(p, data, layout) * jnp.sqrt(w)[:, None]).ravel()

    @fn.defjvp
    def fn_jvp(primals, tangents):
        z, args = primals
        dz, _ = tangents
        r, J = _resid_and_jac(z, *args, layout)
        return r, J @ dz

    return fn


@functools.partial(jax.jit, static_argnames=("layout", "max_steps"))
def _lm(p_full, scale, idx, data, w, layout: Layout, max_steps: int = 40):
    fn = _make_fn(layout)
    solver = optx.LevenbergMarquardt(rtol=1e-6, atol=1e-8, linear_solver=lx.Normal(lx.Cholesky()))
    z0 = jnp.zeros(idx.shape[0], dtype=p_full.dtype)
    sol = optx.least_squares(
        fn, solver, z0, args=(p_full, scale, idx, data, w), max_steps=max_steps, throw=False
    )
    p = p_full.at[idx].add(scale[idx] * sol.value)
    return p, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]


@functools.partial(jax.jit, static_argnames=("layout",))
def _jac(p_full, scale, idx, data, w, layout: Layout):
    z = jnp.zeros(idx.shape[0], dtype=p_full.dtype)
    return _resid_and_jac(z, p_full, scale, idx, data, w, layout)[1]


@functools.partial(jax.jit, static_argnames=("layout",))
def _normal_eq(p_full, scale, idx, data, w, layout: Layout):
    """``(J^T J, J^T r, r^T r)`` at ``p_full`` (scaled active parameters)."""
    z = jnp.zeros(idx.shape[0], dtype=p_full.dtype)
    r, J = _resid_and_jac(z, p_full, scale, idx, data, w, layout)
    return J.T @ J, J.T @ r, r @ r


@functools.partial(jax.jit, static_argnames=("layout",))
def _col_rms(p_full, data, layout: Layout):
    J = _model_jac(p_full, data, layout)
    return jnp.sqrt(jnp.mean(J**2, axis=(0, 1)))


_resid_jit = jax.jit(_residual, static_argnames=("layout",))


# ----------------------------------------------------------------------------- data


@dataclasses.dataclass
class Prepared:
    """A recording turned into fitting arrays (numpy and the JAX ``data`` dict)."""

    rec: Recording
    layout: Layout
    data: dict
    scale: jnp.ndarray
    theta: np.ndarray
    t: np.ndarray
    tau: np.ndarray
    run: np.ndarray
    run_ids: np.ndarray
    temp: np.ndarray | None
    psi: np.ndarray | None
    alpha: np.ndarray
    radius_m: float
    fold: np.ndarray
    order_visibility: np.ndarray
    driver_name: str
    driver_unit: str
    driver_offset: float

    @property
    def n(self) -> int:
        """Number of samples."""
        return self.theta.size

    def idx(self, name: str, sub=None) -> list[int]:
        """Indices of segment ``name`` (optionally a sub-selection of it)."""
        s, n = self.layout.segments[name]
        sel = range(n) if sub is None else sub
        return [s + int(i) for i in sel]


def _where(rec: Recording) -> str:
    return str(rec.path) if rec.path is not None else "recording"


def prepare(rec: Recording, *, max_order: int = 12, runout_orders: int = 6) -> Prepared:
    """Check that ``rec`` can be diagnosed and build the fitting arrays.

    Raises:
        EncdesignInputError: wrong kind, too few heads, samples or revolutions.
    """
    where = _where(rec)
    if rec.kind != "multihead":
        raise input_error(
            f"{where}: kind",
            f"got {rec.kind!r}; diagnosis of {rec.kind!r} recordings is not implemented yet",
            "'multihead', 'quadrature' or 'motion'",
        )
    H = len(rec.head_columns)
    if H < 2:
        raise input_error(f"{where}: [encoder].head_angles_deg", f"{H} head", "at least 2 heads")
    n = rec.n_rows
    if n < 64 * H:
        raise input_error(where, f"only {n} samples", f"at least {64 * H} rows")
    enc = rec.encoder
    alpha = np.deg2rad(np.asarray(enc["head_angles_deg"], float))
    radius = float(enc["optical_radius_m"])
    L = int(enc.get("grating_lines", 0))
    readings = rec.heads()
    run_raw = rec.runs
    run_ids, run = np.unique(run_raw, return_inverse=True)
    # keep file order of runs for the global time axis
    first_row = np.array([np.flatnonzero(run == r)[0] for r in range(run_ids.size)])
    file_order = np.argsort(first_row)
    t = np.asarray(rec.columns["t"], float)
    has_ref = "theta_ref" in rec.columns
    if has_ref:
        theta = np.asarray(rec.columns["theta_ref"], float)
    else:
        theta = readings.mean(1) - readings[0].mean()
    y = readings - theta[:, None]
    # global time: runs laid end to end in file order
    tau = np.empty(n)
    offset = 0.0
    for r in file_order:
        rows = np.flatnonzero(run == r)
        tr = t[rows]
        dt = np.median(np.diff(tr)) if rows.size > 1 else 1.0
        tau[rows] = tr - tr[0] + offset
        offset = tau[rows][-1] + dt
    order_rows = np.argsort(tau, kind="stable")
    if np.any(order_rows != np.arange(n)):
        raise input_error(
            where, "rows of the runs are interleaved", "each run's rows together, in time order"
        )
    # folds: even / odd revolutions of each run
    fold = np.zeros(n, dtype=int)
    for r in range(run_ids.size):
        rows = np.flatnonzero(run == r)
        th = theta[rows]
        revs = abs(th[-1] - th[0]) / (2 * np.pi)
        if revs >= 2:
            blk = np.floor(np.abs(th - th[0]) / (2 * np.pi)).astype(int)
        else:
            blk = np.floor(np.arange(rows.size) / rows.size * 8).astype(int)
        fold[rows] = blk % 2
    if np.all(fold == 0) or np.all(fold == 1):
        raise input_error(where, "too short to hold data out", "at least two revolutions")
    total_revs = sum(
        abs(theta[run == r][-1] - theta[run == r][0]) / (2 * np.pi) for r in range(run_ids.size)
    )
    if total_revs < 0.9:
        raise input_error(
            where, f"covers {total_revs:.2f} revolutions", "at least one revolution of the shaft"
        )
    temp = np.asarray(rec.columns["temp_c"], float) if "temp_c" in rec.columns else None
    if temp is not None and np.ptp(temp) > 0:
        driver = temp - temp.mean()
        driver_name, driver_unit, driver_offset = "temp_c", "K", float(temp.mean())
    else:
        driver = tau - tau.mean()
        driver_name, driver_unit, driver_offset = "time", "s", float(tau.mean())
    psi = np.mod(L * np.mod(readings, 2 * np.pi / L), 2 * np.pi) if L > 0 else None
    psi_mask = np.zeros((n, H))
    if psi is not None:
        for k in range(H):
            psi_mask[:, k] = np.isin(run, line_phase_runs(psi[:, k], run))
    # which orders are visible to the fit
    M = max_order
    vis = np.ones(M)
    if not has_ref:
        for m in range(1, M + 1):
            v = np.exp(-1j * m * alpha)
            vis[m - 1] = float(np.sum(np.abs(v - v.mean()) ** 2) / H)
    R = run_ids.size
    n_base = H + 2 * M + H
    eff_sizes = sorted([H + 2 * runout_orders, 1 + 2 * R, 1 + 2 * R * H, H, 4 * H, 3])
    sizes = (n_base + eff_sizes[-1], n_base + sum(eff_sizes[-3:]))
    layout = Layout(H, M, R, runout_orders, L, has_ref, sizes[-1], sizes)
    dt_med = float(np.median(np.diff(tau)))
    onehot = np.zeros((n, R))
    onehot[np.arange(n), run] = 1.0
    data = dict(
        theta=jnp.asarray(theta),
        t=jnp.asarray(t),
        tau=jnp.asarray(tau),
        onehot=jnp.asarray(onehot),
        driver=jnp.asarray(driver),
        psi=jnp.asarray(psi if psi is not None else np.zeros((n, H))),
        psi_mask=jnp.asarray(psi_mask),
        y=jnp.asarray(y),
        alpha=jnp.asarray(alpha),
        radius_m=jnp.asarray(radius),
        width_s=jnp.asarray(0.5 * dt_med),
    )
    sc = np.ones(layout.size + 1)
    seg = layout.segments
    u = 1e-6

    def put(name, v):
        s, k = seg[name]
        sc[s : s + k] = v

    put("c", u)
    put("a", u)
    put("b", u)
    put("d", 1e-4)
    put("bt_beta", 1e-2)
    put("bt_zc", u * radius / 1e-2)
    put("bt_zs", u * radius / 1e-2)
    put("wb_nu", 1e-3)
    put("wb_A", u * radius)
    put("wb_B", u * radius)
    put("vb_f", 1e-3)
    put("vb_C", u)
    put("vb_S", u)
    put("th_k", u / max(float(np.std(driver)), 1e-12))
    put("ip", u * max(L, 1))
    put("es_t", dt_med)
    put("es_x", u * radius)
    put("es_y", u * radius)
    return Prepared(
        rec=rec,
        layout=layout,
        data=data,
        scale=jnp.asarray(sc),
        theta=theta,
        t=t,
        tau=tau,
        run=run,
        run_ids=run_ids,
        temp=temp,
        psi=psi,
        alpha=alpha,
        radius_m=radius,
        fold=fold,
        order_visibility=vis,
        driver_name=driver_name,
        driver_unit=driver_unit,
        driver_offset=driver_offset,
    )


# ----------------------------------------------------------------------------- fitting


@dataclasses.dataclass
class FitState:
    """Parameters, the active index set, the residual and its sums of squares."""

    p: np.ndarray
    active: list[int]
    resid: np.ndarray
    ssr: float
    ok: bool
    heldout_ssr: float = float("nan")
    heldout_n: int = 0

    @property
    def heldout_rms(self) -> float:
        """RMS of the held-out residual (rad)."""
        return math.sqrt(self.heldout_ssr / max(self.heldout_n, 1))


def _scales(prep: Prepared, p: np.ndarray) -> np.ndarray:
    """Column scaling: a unit step of each scaled parameter moves the model by ~1 urad RMS."""
    lay = prep.layout
    rms = np.asarray(_col_rms(jnp.asarray(p), prep.data, layout=lay))
    sc = np.array(prep.scale)
    ok = rms > 1e-300
    sc[: lay.size][ok] = 1e-6 / rms[ok]
    return sc


def _sized(layout: Layout, n: int) -> Layout:
    """The layout whose gathered length is the smallest compiled size holding ``n``."""
    for k in layout.active_sizes or (layout.n_active,):
        if n <= k:
            return dataclasses.replace(layout, n_active=k)
    raise RuntimeError(f"{n} active parameters exceed the compiled {layout.n_active}")


def _run_lm(prep: Prepared, p: np.ndarray, active: list[int], w: np.ndarray):
    lay = _sized(prep.layout, len(active))
    idx = np.full(lay.n_active, lay.size, dtype=np.int64)
    idx[: len(active)] = sorted(active)
    sc = _scales(prep, p)
    jidx, jw, jsc = jnp.asarray(idx), jnp.asarray(w), jnp.asarray(sc)
    # Gauss-Newton warm start (exact for the linear parameters), then Levenberg-Marquardt
    for _ in range(3):
        A, g, ssr = (
            np.asarray(v) for v in _normal_eq(jnp.asarray(p), jsc, jidx, prep.data, jw, layout=lay)
        )
        A = A + 1e-9 * np.trace(A) / A.shape[0] * np.eye(A.shape[0])
        try:
            dz = -np.linalg.solve(A, g)
        except np.linalg.LinAlgError:
            break
        q = p.copy()
        q[idx] += sc[idx] * dz
        q[lay.size] = 0.0
        r_new = float(np.sum((_resid(prep, q) ** 2) * w[:, None]))
        if not r_new < ssr:
            break
        p = q
        if ssr - r_new < 1e-8 * ssr:
            break
    p_out, ok, _ = _lm(jnp.asarray(p), jsc, jidx, prep.data, jw, layout=lay)
    p_out = np.array(p_out)
    p_out[lay.size] = 0.0
    return p_out, bool(ok)


def _resid(prep: Prepared, p: np.ndarray) -> np.ndarray:
    return np.asarray(_resid_jit(jnp.asarray(p), prep.data, layout=prep.layout))


def _fit(prep: Prepared, p0: np.ndarray, active: list[int], *, heldout: bool = True) -> FitState:
    w = np.ones(prep.n)
    p, ok = _run_lm(prep, p0, active, w)
    r = _resid(prep, p)
    st = FitState(p=p, active=list(active), resid=r, ssr=float(np.sum(r**2)), ok=ok)
    if heldout:
        ho_ssr, ho_n = 0.0, 0
        for f in (0, 1):
            wf = (prep.fold != f).astype(float)
            pf, okf = _run_lm(prep, p, active, wf)
            rf = _resid(prep, pf)[prep.fold == f]
            ho_ssr += float(np.sum(rf**2))
            ho_n += rf.size
            st.ok = st.ok and okf
        st.heldout_ssr, st.heldout_n = ho_ssr, ho_n
    return st


def _base_active(prep: Prepared, *, placement: bool) -> list[int]:
    lay = prep.layout
    orders = [m for m in range(lay.max_order) if prep.order_visibility[m] > 0.05]
    act = prep.idx("c", range(0 if lay.has_ref else 1, lay.n_heads))
    act += prep.idx("a", orders) + prep.idx("b", orders)
    if placement:
        act += prep.idx("d", range(1, lay.n_heads))
    return act


def fit_base(prep: Prepared) -> FitState:
    """Least-squares fit of the base model (linear pass, then with head placement)."""
    p0 = np.zeros(prep.layout.size + 1)
    st = _fit(prep, p0, _base_active(prep, placement=False), heldout=False)
    return _fit(prep, st.p, _base_active(prep, placement=True))


# ----------------------------------------------------------------------------- candidates


def _locate_input(prep: Prepared, resid: np.ndarray, sigma: np.ndarray) -> LocateInput:
    return LocateInput(
        resid=resid,
        run=prep.run,
        t=prep.t,
        tau=prep.tau,
        theta=prep.theta,
        temp=prep.temp,
        psi=prep.psi,
        alpha=prep.alpha,
        sigma=sigma,
        has_ref=prep.layout.has_ref,
    )


def candidates_for(f: Finding, layout: Layout) -> list[str]:
    """Catalog effects whose signature is consistent with finding ``f``."""
    if f.view == "line_phase":
        return ["interpolation_error"] if layout.grating_lines > 0 else []
    if f.view == "drift":
        return ["thermal_drift"]
    if f.view == "change_point":
        return ["eccentricity_shift"] if f.detail["step"] == "step_order1" else ["thermal_drift"]
    if f.view == "repeatability":
        return ["beam_tilt_axial"]
    if f.view == "spectrum":
        fixed = f.detail["fixed_in"]
        integer = f.detail["integer_order"]
        out = []
        if integer and fixed != "hz":
            if all(round(o) <= layout.runout_orders for o in f.where["orders"]):
                out.append("beam_tilt_axial")
            if fixed in ("undetermined", "single_run"):
                out.append("vibration")
        elif not integer:
            # both: with short runs the Hz/order classification can be ambiguous, and the
            # information criterion and held-out data decide between them
            out += ["vibration", "bearing_wobble"]
        if fixed == "hz" and "vibration" not in out:
            out.append("vibration")
        return out
    return []


def _overlaps(g: Finding, f: Finding) -> bool:
    """Whether a later finding ``g`` sits where ``f`` was (same view, heads and place)."""
    if g.view != f.view or not set(g.where["heads"]) & set(f.where["heads"]):
        return False
    if f.view == "spectrum":
        for a, oa in zip(f.where["frequencies_hz"], f.where["orders"]):
            for b, ob in zip(g.where["frequencies_hz"], g.where["orders"]):
                if abs(a - b) <= 0.2 * abs(a) or abs(oa - ob) <= 0.2 * abs(oa):
                    return True
        return False
    if f.view == "repeatability":
        return bool(set(g.where["runs"]) & set(f.where["runs"]))
    if f.view == "change_point":
        return g.detail["step"] == f.detail["step"]
    if f.view == "drift":
        return g.detail["driver"] == f.detail["driver"]
    return True


def _init_candidate(
    name: str, prep: Prepared, state: FitState, findings: list[Finding], sigma: np.ndarray
) -> list[tuple[np.ndarray, list[list[int]]]]:
    """Starting points and active-set stages for fitting candidate ``name``.

    Returns a list of alternatives, each ``(p0, [stage1_extra, stage2_extra])``: the linear
    parameters are fitted first with the nonlinear ones held, then everything together.
    """
    lay = prep.layout
    p = state.p.copy()
    alts = []
    mine = [f for f in findings if name in candidates_for(f, lay)]
    if name == "vibration":
        freqs = []
        for f in mine:
            if f.view == "spectrum":
                freqs.append(f.where["frequencies_hz"][0])
        for fr in freqs[:2]:
            q = p.copy()
            q[prep.idx("vb_f")[0]] = fr
            lin = prep.idx("vb_C") + prep.idx("vb_S")
            alts.append((q, [lin, lin + prep.idx("vb_f")]))
    elif name == "bearing_wobble":
        for f in mine:
            if f.view == "spectrum":
                q = p.copy()
                q[prep.idx("wb_nu")[0]] = float(np.median(f.where["orders"]))
                lin = prep.idx("wb_A") + prep.idx("wb_B")
                alts.append((q, [lin, lin + prep.idx("wb_nu")]))
                if len(alts) == 2:
                    break
    elif name == "beam_tilt_axial":
        orders = set()
        for f in mine:
            if f.view == "spectrum":
                orders |= {int(round(o)) for o in f.where["orders"]}
            elif f.view == "repeatability":
                orders |= _profile_orders(prep, state.resid, f, lay.runout_orders)
        orders = sorted(o for o in orders if 1 <= o <= lay.runout_orders)
        if orders:
            lin = (
                prep.idx("bt_beta")
                + prep.idx("bt_zc", [o - 1 for o in orders])
                + prep.idx("bt_zs", [o - 1 for o in orders])
            )
            # two starts: the current state, and one with the head placements reset (a
            # head-specific order-1 error is partly absorbed by placement errors, which
            # multiply the large eccentricity: a valley the joint fit may not leave)
            p_nod = p.copy()
            p_nod[prep.idx("d")] = 0.0
            for q0, res in ((p, state.resid), (p_nod, _resid(prep, p_nod))):
                q = q0.copy()
                beta, zc, zs = _rank1_beam(prep, res, orders)
                q[prep.idx("bt_beta")] = beta
                q[prep.idx("bt_zc", [o - 1 for o in orders])] = zc
                q[prep.idx("bt_zs", [o - 1 for o in orders])] = zs
                alts.append((q, [lin, lin]))
    elif name == "thermal_drift":
        lin = prep.idx("th_k")
        alts.append((p.copy(), [lin, lin]))
    elif name == "interpolation_error":
        if lay.grating_lines > 0:
            lin = prep.idx("ip")
            alts.append((p.copy(), [lin, lin]))
    elif name == "eccentricity_shift":
        for f in mine:
            if f.view == "change_point":
                q = p.copy()
                q[prep.idx("es_t")[0]] = f.detail["global_time_s"]
                lin = prep.idx("es_x") + prep.idx("es_y")
                alts.append((q, [lin, lin + prep.idx("es_t")]))
                break
    return alts


def _profile_orders(prep: Prepared, resid: np.ndarray, f: Finding, max_m: int) -> set[int]:
    rows = np.isin(prep.run, f.where["runs"])
    best = []
    for m in range(1, max_m + 1):
        pw = 0.0
        for k in f.where["heads"]:
            z = np.sum(resid[rows, k] * np.exp(-1j * m * prep.theta[rows]))
            pw += abs(z) ** 2
        best.append((pw, m))
    best.sort(reverse=True)
    return {m for pw, m in best[:2] if pw > 0.2 * best[0][0]}


def _rank1_beam(prep: Prepared, resid: np.ndarray, orders: list[int]):
    """Start for ``beta_k z_m``: a grid over the runout phase of the strongest order.

    At order ``m`` head ``k``'s residual is ``c_k cos m theta + s_k sin m theta``. The
    effect gives ``(c_k, s_k) = b_k (cos phi, sin phi)`` with ``b_k = beta_k |z| / R``, the
    base model can still absorb ``a cos m(theta - alpha_k) + b sin m(...)`` and, without a
    reference angle, a common term. For each phase ``phi`` on a grid that is linear in
    ``b_k``, ``a``, ``b``: the best phase is kept (the product is bilinear, so a plain
    rank-1 start can fall into a wrong valley).
    """
    H = prep.layout.n_heads
    al = prep.alpha
    cs = {}
    for m in orders:
        X = np.stack([np.cos(m * prep.theta), np.sin(m * prep.theta)], 1)
        coef, *_ = np.linalg.lstsq(X, resid, rcond=None)  # (2, H)
        cs[m] = coef
    m0 = max(orders, key=lambda m: float(np.sum(cs[m] ** 2)))

    def design(m, u):
        # rows: c_0..c_{H-1}, s_0..s_{H-1}; columns: b_k (H), a, b, [gc, gs]
        cols = []
        for k in range(H):
            v = np.zeros(2 * H)
            v[k], v[H + k] = u
            cols.append(v)
        ca, sa = np.cos(m * al), np.sin(m * al)
        cols.append(np.concatenate([ca, sa]))
        cols.append(np.concatenate([-sa, ca]))
        if not prep.layout.has_ref:
            cols.append(np.concatenate([np.ones(H), np.zeros(H)]))
            cols.append(np.concatenate([np.zeros(H), np.ones(H)]))
        return np.stack(cols, 1)

    y0 = np.concatenate([cs[m0][0], cs[m0][1]])
    best = None
    for phi in np.linspace(0, np.pi, 72, endpoint=False):
        A = design(m0, (np.cos(phi), np.sin(phi)))
        sol, *_ = np.linalg.lstsq(A, y0, rcond=None)
        ssr = float(np.sum((A @ sol - y0) ** 2))
        if best is None or ssr < best[0]:
            best = (ssr, phi, sol[:H])
    _, phi, bk = best
    s = max(float(np.max(np.abs(bk))), 1e-30) / 1e-2
    beta = bk / s
    zc, zs = [], []
    for m in orders:
        if m == m0:
            zc.append(s * prep.radius_m * np.cos(phi))
            zs.append(s * prep.radius_m * np.sin(phi))
            continue
        # given beta: (c_k, s_k) = beta_k (zc, zs)/R + base terms
        A = np.zeros((2 * H, 2))
        A[:H, 0] = beta / prep.radius_m
        A[H:, 1] = beta / prep.radius_m
        full = np.concatenate([A, design(m, (0.0, 0.0))[:, H:]], 1)
        y = np.concatenate([cs[m][0], cs[m][1]])
        sol, *_ = np.linalg.lstsq(full, y, rcond=None)
        zc.append(sol[0])
        zs.append(sol[1])
    return beta, np.asarray(zc), np.asarray(zs)


# ----------------------------------------------------------------------------- results


@dataclasses.dataclass
class EffectResult:
    """One named effect.

    Attributes:
        name: catalog name. params: physical parameters (SI) with standard errors.
        rms_after, heldout_rms_after: residual RMS (rad) once this effect (and those named
            before it) are in the model, on fitted and on held-out data.
        delta_bic: information-criterion change when it was added (negative = better).
        explanation: plain-language account of what the simulation left out.
        collinearity: largest canonical correlation with the base parameters (0..1).
        notes: caveats (confounding, unidentifiable parts).
    """

    name: str
    params: dict[str, Any]
    rms_after: float
    heldout_rms_after: float
    delta_bic: float
    explanation: str
    collinearity: float
    notes: list[str]

    def to_json(self) -> dict[str, Any]:
        """Plain-JSON form."""
        return dataclasses.asdict(self)


@dataclasses.dataclass
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes:
        verdict: ``consistent`` | ``missing_physics`` | ``unexplained``.
        rms_before, heldout_rms_before: base-model residual RMS (rad), fitted / held out.
        rms_final, heldout_rms_final: with every named effect.
        effects: named effects, most important first.
        unexplained: structure no catalog effect explains, each ``{where, rms, view, ...}``.
        rejected: candidates tried and why they were not named.
        base: base-model parameters with standard errors, and what is unidentifiable.
        findings_before: what the views located in the base residual.
        noise_rad: per-head white-noise std estimate (rad).
        status: ``ok`` or a description of solver trouble.
        time_s: wall time of the diagnosis.
    """

    verdict: str
    rms_before: float
    heldout_rms_before: float
    rms_final: float
    heldout_rms_final: float
    effects: list[EffectResult]
    unexplained: list[dict[str, Any]]
    rejected: list[dict[str, Any]]
    base: dict[str, Any]
    findings_before: list[dict[str, Any]]
    noise_rad: list[float]
    status: str
    time_s: float
    source: str = ""
    _plot_data: dict[str, Any] = dataclasses.field(default_factory=dict, repr=False)

    def to_json(self) -> dict[str, Any]:
        """The CLI's JSON document."""
        return {
            "verdict": self.verdict,
            "rms_before": self.rms_before,
            "heldout_rms_before": self.heldout_rms_before,
            "rms_final": self.rms_final,
            "heldout_rms_final": self.heldout_rms_final,
            "effects": [e.to_json() for e in self.effects],
            "unexplained": self.unexplained,
            "rejected": self.rejected,
            "base": self.base,
            "findings_before": self.findings_before,
            "noise_rad": self.noise_rad,
            "status": self.status,
            "time_s": self.time_s,
            "source": self.source,
            "units": "rad unless a key names another unit (_m, _hz, _s, _k)",
        }


def _cov_se(prep: Prepared, st: FitState, sigma2: float) -> dict[int, float]:
    """Standard errors (parameter units) of the active parameters, from J^T J."""
    lay = _sized(prep.layout, len(st.active))
    idx = np.full(lay.n_active, lay.size, dtype=np.int64)
    idx[: len(st.active)] = sorted(st.active)
    scale = _scales(prep, st.p)
    J = np.asarray(
        _jac(
            jnp.asarray(st.p),
            jnp.asarray(scale),
            jnp.asarray(idx),
            prep.data,
            jnp.ones(prep.n),
            layout=lay,
        )
    )[:, : len(st.active)]
    cov = np.linalg.pinv(J.T @ J, rcond=1e-10) * sigma2
    sc = scale[idx[: len(st.active)]]
    se = np.sqrt(np.maximum(np.diag(cov), 0.0)) * sc
    return {int(i): float(s) for i, s in zip(idx[: len(st.active)], se)}, J


def _collinearity(J: np.ndarray, active: list[int], base_set: set[int]) -> float:
    order = sorted(active)
    bcols = [i for i, a in enumerate(order) if a in base_set]
    ecols = [i for i, a in enumerate(order) if a not in base_set]
    if not bcols or not ecols:
        return 0.0

    def orth(A):
        u, s, _ = np.linalg.svd(A, full_matrices=False)
        return u[:, s > 1e-9 * max(s.max(), 1e-300)]

    qb, qe = orth(J[:, bcols]), orth(J[:, ecols])
    if qb.size == 0 or qe.size == 0:
        return 0.0
    return float(np.linalg.svd(qb.T @ qe, compute_uv=False).max())


def _vals(p, prep, name):
    s, n = prep.layout.segments[name]
    return p[s : s + n]


def _ses(se, prep, name):
    return [se.get(i, float("nan")) for i in prep.idx(name)]


def _nan_none(x):
    if isinstance(x, list):
        return [_nan_none(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _effect_params(name: str, prep: Prepared, st: FitState, se: dict[int, float]) -> dict:
    lay = prep.layout
    p = st.p
    H, R = lay.n_heads, lay.n_runs
    out: dict[str, Any] = {}
    if name == "vibration":
        f = float(_vals(p, prep, "vb_f")[0])
        C = _vals(p, prep, "vb_C").reshape(R, H)
        S = _vals(p, prep, "vb_S").reshape(R, H)
        amp = np.hypot(C, S)
        present = amp.max(1) > 0.2 * amp.max()
        out["frequency_hz"] = f
        out["frequency_hz_se"] = _ses(se, prep, "vb_f")[0]
        out["amplitude_rad_per_head"] = [float(v) for v in amp[present].mean(0)]
        out["amplitude_rad_per_run_head"] = amp.tolist()
        out["phase_rad_per_run_head"] = np.arctan2(C, S).tolist()
        out["runs_present"] = [int(prep.run_ids[r]) for r in np.flatnonzero(present)]
        spread = amp[present].std(0).mean() / max(amp[present].mean(), 1e-300)
        ph = np.angle(S + 1j * C)[present]
        pspread = float(np.abs(np.exp(1j * ph) - np.exp(1j * ph).mean(1, keepdims=True)).mean())
        out["mode"] = "common" if spread < 0.2 and pspread < 0.2 else "per_head"
        sev = _ses(se, prep, "vb_C")
        out["amplitude_rad_se"] = float(np.nanmedian(sev)) if sev else None
    elif name == "bearing_wobble":
        A = _vals(p, prep, "wb_A")
        B = _vals(p, prep, "wb_B")
        rho = np.hypot(A, B)
        out["frequency_ratio"] = float(_vals(p, prep, "wb_nu")[0])
        out["frequency_ratio_se"] = _ses(se, prep, "wb_nu")[0]
        out["runout_m"] = float(rho.mean())
        out["runout_m_se"] = float(np.nanmedian(_ses(se, prep, "wb_A")))
        out["runout_m_per_run"] = rho.tolist()
        out["phase_rad_per_run"] = np.arctan2(B, A).tolist()
    elif name == "beam_tilt_axial":
        beta = _vals(p, prep, "bt_beta")
        zc, zs = _vals(p, prep, "bt_zc"), _vals(p, prep, "bt_zs")
        za = np.hypot(zc, zs)
        orders = [m + 1 for m in range(lay.runout_orders) if za[m] > 0]
        prod = np.abs(beta)[:, None] * za[None, :]
        out["runout_orders"] = orders
        out["error_amplitude_rad"] = [
            [float(prod[k, m - 1] / prep.radius_m) for m in orders] for k in range(H)
        ]
        out["tilt_runout_product_m_rad"] = [
            [float(prod[k, m - 1]) for m in orders] for k in range(H)
        ]
        zref = 2.54e-6
        zmax = max(za.max(), 1e-300)
        out["assumed_axial_runout_m"] = zref
        out["beam_tilt_rad"] = [float(b * zmax / zref) for b in beta]
        out["axial_runout_m"] = {
            str(m): [float(zc[m - 1] / zmax * zref), float(zs[m - 1] / zmax * zref)] for m in orders
        }
        if not lay.has_ref:
            out["note"] = "without theta_ref only beta_k minus the head mean is observable"
    elif name == "thermal_drift":
        k = _vals(p, prep, "th_k")
        unit = prep.driver_unit
        key = "rate_rad_per_k" if unit == "K" else "rate_rad_per_s"
        out[key] = k.tolist()
        out[key + "_se"] = _ses(se, prep, "th_k")
        if unit == "K":
            out["rate_arcsec_per_k"] = [float(v / fx.ARCSEC_RAD) for v in k]
            out["reference_temp_c"] = prep.driver_offset
        out["driver"] = prep.driver_name
    elif name == "interpolation_error":
        c = _vals(p, prep, "ip").reshape(4, H)
        out["grating_lines"] = lay.grating_lines
        out["offset_a"] = c[0].tolist()
        out["offset_b"] = (-c[1]).tolist()
        out["amplitude_error"] = (-2 * c[3]).tolist()
        out["phase_error_rad"] = (-2 * c[2]).tolist()
        L = lay.grating_lines
        out["amplitude_1x_pitch_rad"] = (np.hypot(c[0], c[1]) / L).tolist()
        out["amplitude_2x_pitch_rad"] = (np.hypot(c[2], c[3]) / L).tolist()
        out["note"] = "offset/amplitude/phase split assumes each head's zero lies on a line"
    elif name == "eccentricity_shift":
        ts = float(_vals(p, prep, "es_t")[0])
        dx, dy = float(_vals(p, prep, "es_x")[0]), float(_vals(p, prep, "es_y")[0])
        i = int(np.clip(np.searchsorted(prep.tau, ts), 0, prep.n - 1))
        out["shift_time_s"] = float(prep.t[i] + (ts - prep.tau[i]))
        out["shift_run"] = int(prep.run_ids[prep.run[i]])
        out["shift_global_time_s"] = ts
        out["shift_time_s_se"] = _ses(se, prep, "es_t")[0]
        out["shift_x_m"], out["shift_y_m"] = dx, dy
        out["shift_m"] = float(math.hypot(dx, dy))
        out["shift_m_se"] = float(np.nanmax(_ses(se, prep, "es_x") + _ses(se, prep, "es_y")))
    return {k: _nan_none(v) for k, v in out.items()}


def _explain(name: str, params: dict, prep: Prepared) -> str:
    R = prep.radius_m
    if name == "vibration":
        return (
            f"The heads and the scale oscillate relative to each other at "
            f"{params['frequency_hz']:.3f} Hz (amplitude about "
            f"{np.mean(params['amplitude_rad_per_head']) * 1e6:.2f} urad, {params['mode']}). "
            "It stays at the same frequency in Hz whatever the shaft speed, so it is a "
            "structural vibration, not a property of the disk; the simulation had no "
            "vibration term."
        )
    if name == "bearing_wobble":
        return (
            f"The shaft centre runs out by about {params['runout_m'] * 1e9:.0f} nm at "
            f"{params['frequency_ratio']:.3f} times the shaft speed: a bearing (cage, balls) "
            "moves the axis in a way that does not repeat each revolution. The simulation "
            "assumed the rotation axis fixed; opposed heads cancel it, single heads do not."
        )
    if name == "beam_tilt_axial":
        amp = np.max(params["error_amplitude_rad"]) if params["error_amplitude_rad"] else 0
        return (
            f"Axial runout of the disk at shaft order(s) {params['runout_orders']} is read "
            "through beams that are not parallel to the axis, so each head sees its own "
            f"error (up to {amp * 1e6:.2f} urad) rather than a phase-shifted copy of the "
            "others. The simulation assumed beams parallel to the axis (seed 001, axial "
            "shifts); this error does not cancel by symmetry averaging."
        )
    if name == "thermal_drift":
        key = "rate_arcsec_per_k" if "rate_arcsec_per_k" in params else "rate_rad_per_s"
        vals = ", ".join(f"{v:.3g}" for v in params[key])
        unit = "arcsec/K" if key == "rate_arcsec_per_k" else "rad/s"
        return (
            f"Head readings drift with {params['driver']} ({vals} {unit} per head): "
            "thermal expansion of mounts and disk (seed 001 reports about 0.7 arcsec/K). "
            "The simulation assumed a constant temperature."
        )
    if name == "interpolation_error":
        a1 = max(params["amplitude_1x_pitch_rad"]) * 1e6
        a2 = max(params["amplitude_2x_pitch_rad"]) * 1e6
        return (
            f"The heads' sin/cos signals have offsets, unequal amplitudes or a phase error, "
            f"so arctangent interpolation errs periodically within each grating pitch (up to "
            f"{a1:.2f} urad at 1x and {a2:.2f} urad at 2x the line frequency, orders "
            f"{prep.layout.grating_lines} and {2 * prep.layout.grating_lines}). The simulation "
            "assumed ideal quadrature signals."
        )
    if name == "eccentricity_shift":
        return (
            f"The disk moved on its hub by {params['shift_m'] * 1e9:.0f} nm "
            f"({params['shift_m'] / R * 1e6:.2f} urad of order-1 error) at t = "
            f"{params['shift_time_s']:.3f} s of run {params['shift_run']}: a shock or slip. "
            "The simulation assumed one fixed centring error for the whole record."
        )
    return name


def _base_report(prep: Prepared, st: FitState, se: dict[int, float], sigma) -> dict:
    lay = prep.layout
    a, b = _vals(st.p, prep, "a"), _vals(st.p, prep, "b")
    vis = prep.order_visibility
    unident = []
    if not lay.has_ref:
        unident.append("the common part of the head constants c_k (only differences)")
        unident.append("every error common to all heads at one sample (shaft angle unknown)")
        bad = [m + 1 for m in range(lay.max_order) if vis[m] <= 0.05]
        if bad:
            unident.append(
                f"disk error orders {bad}: the same at every head (multiples of the head "
                "symmetry), they cancel in head differences"
            )
        weak = [m + 1 for m in range(lay.max_order) if 0.05 < vis[m] < 0.3]
        if weak:
            unident.append(f"orders {weak} are weakly determined (near-degenerate head pattern)")
    unident.append("the common rotation of all heads (placement of head 0 is the reference)")
    return {
        "max_order": lay.max_order,
        "has_theta_ref": lay.has_ref,
        "head_constants_rad": _vals(st.p, prep, "c").tolist(),
        "head_constants_rad_se": _nan_none(_ses(se, prep, "c")),
        "fourier_cos_rad": a.tolist(),
        "fourier_sin_rad": b.tolist(),
        "fourier_cos_rad_se": _nan_none(_ses(se, prep, "a")),
        "fourier_sin_rad_se": _nan_none(_ses(se, prep, "b")),
        "fourier_amplitude_rad": np.hypot(a, b).tolist(),
        "disk_eccentricity_m": [float(b[0] * prep.radius_m), float(a[0] * prep.radius_m)],
        "disk_eccentricity_m_se": _nan_none(
            [
                se.get(prep.idx("b")[0], float("nan")) * prep.radius_m,
                se.get(prep.idx("a")[0], float("nan")) * prep.radius_m,
            ]
        ),
        "head_placement_rad": _vals(st.p, prep, "d").tolist(),
        "head_placement_rad_se": _nan_none(_ses(se, prep, "d")),
        "noise_rad": [float(s) for s in sigma],
        "order_visibility": vis.tolist(),
        "unidentifiable": unident,
    }


def _progress(msg: str, verbose: bool) -> None:
    if verbose:
        print(f"diagnose: {msg}", file=sys.stderr, flush=True)


def diagnose(
    recording: Recording | str | os.PathLike,
    *,
    max_order: int = 12,
    max_effects: int = 3,
    verbose: bool = False,
    throw: bool = False,
) -> Diagnosis:
    """Diagnose a multihead recording against the base model.

    Args:
        recording: a :class:`~encdesign.Recording` or the path of its TOML file.
        max_order: highest disk error order of the base model.
        max_effects: most catalog effects to add.
        verbose: progress lines on stderr.
        throw: raise ``RuntimeError`` when a least-squares solve did not converge
            (otherwise ``status`` says so).

    Returns:
        A :class:`Diagnosis` (``to_json()`` gives the CLI document).

    Raises:
        EncdesignInputError: the recording cannot be diagnosed (kind, size, layout).
    """
    import time

    t0 = time.perf_counter()
    rec = recording if isinstance(recording, Recording) else load_recording(recording)
    prep = prepare(rec, max_order=max_order)
    lay = prep.layout
    _progress("fitting the base model", verbose)
    base = fit_base(prep)
    sigma = noise_sigma(base.resid, prep.run)
    s2 = float(np.mean(sigma**2))
    N = base.resid.size * (1 if lay.has_ref else (lay.n_heads - 1) / lay.n_heads)
    linp = _locate_input(prep, base.resid, sigma)
    L = lay.grating_lines
    findings0 = locate(linp, line_orders=(L, 2 * L) if L else ())
    _progress(
        f"base rms {math.sqrt(base.ssr / base.resid.size):.3g} rad, {len(findings0)} finding(s)",
        verbose,
    )
    base_set = set(base.active)
    current, findings = base, findings0
    effects: list[EffectResult] = []
    rejected: list[dict] = []
    status_ok = base.ok
    named: set[str] = set()
    for _ in range(max_effects):
        cands = []
        for f in findings:
            for c in candidates_for(f, lay):
                if c not in cands and c not in named:
                    cands.append(c)
        if not cands:
            break
        fits = []
        for name in cands:
            _progress(f"trying {name}", verbose)
            best = None
            for p0, stages in _init_candidate(name, prep, current, findings, sigma):
                st1 = _fit(prep, p0, current.active + stages[0], heldout=False)
                st = _fit(prep, st1.p, current.active + stages[1], heldout=False)
                if best is None or st.ssr < best[0].ssr:
                    best = (st, stages[1])
            if best is None:
                rejected.append(dict(name=name, reason="no starting point from the findings"))
                continue
            st, extra = best
            dchi = (current.ssr - st.ssr) / s2
            dbic = -(dchi - len(extra) * math.log(N))
            fits.append((dbic, name, st, extra, dchi))
        fits.sort(key=lambda x: x[0])
        trials = []
        for dbic, name, st, extra, dchi in fits:
            if any(not t[4] for t in trials):
                rejected.append(
                    dict(
                        name=name,
                        reason=f"{trials[-1][0]} lowers the criterion more "
                        f"(dBIC {trials[-1][3]:.1f} vs {dbic:.1f})",
                        delta_bic=dbic,
                    )
                )
                continue
            reasons = []
            if dbic > -10:
                reasons.append(f"information criterion not lowered enough (dBIC {dbic:.1f})")
                trials.append((name, st, extra, dbic, reasons, [], dchi))
                continue
            st = _fit(prep, st.p, st.active)
            dho = (current.heldout_ssr - st.heldout_ssr) / s2
            lin_new = _locate_input(prep, st.resid, sigma)
            new_f = locate(lin_new, line_orders=(L, 2 * L) if L else ())
            motiv = [f for f in findings if name in candidates_for(f, lay)]
            before = sum(f.power for f in motiv)
            after = sum(finding_power(f, lin_new, st.resid) for f in motiv)
            left = [g for g in new_f for f in motiv if _overlaps(g, f)]
            if dho <= 10 or st.heldout_ssr >= current.heldout_ssr:
                reasons.append(
                    f"held-out RMS {current.heldout_rms:.3g} -> {st.heldout_rms:.3g} rad "
                    "not improved"
                )
            if left:
                reasons.append(
                    f"leaves significant structure where it was located "
                    f"({left[0].view}, heads {left[0].where['heads']})"
                )
            if before > 0 and after > 0.5 * before:
                reasons.append(f"explains only {100 * (1 - after / before):.0f}% of it")
            # it must also carry a fair share of everything located, so that a larger
            # structure it cannot explain is not pinned on it through a small part
            tot = sum(f.power for f in findings)
            left_all = sum(min(finding_power(f, lin_new, st.resid), f.power) for f in findings)
            if tot > 0 and tot - left_all < 0.3 * tot:
                reasons.append(
                    f"explains only {100 * (tot - left_all) / tot:.0f}% of all located structure"
                )
            trials.append((name, st, extra, dbic, reasons, new_f, dchi))
            status_ok = status_ok and st.ok
        good = [t for t in trials if not t[4]]
        for name, _st, _extra, dbic, reasons, _, _ in trials:
            if reasons:
                rejected.append(dict(name=name, reason="; ".join(reasons), delta_bic=dbic))
        if not good:
            break
        name, st, extra, dbic, _, new_f, dchi = good[0]
        se, J = _cov_se(prep, st, s2)
        params = _effect_params(name, prep, st, se)
        col = _collinearity(J, st.active, base_set)
        notes = []
        if col > 0.95:
            notes.append(
                f"nearly collinear with base parameters (canonical correlation {col:.3f}): "
                "part of it could be absorbed by the base model"
            )
        effects.append(
            EffectResult(
                name=name,
                params=params,
                rms_after=math.sqrt(st.ssr / st.resid.size),
                heldout_rms_after=st.heldout_rms,
                delta_bic=dbic,
                explanation=_explain(name, params, prep),
                collinearity=col,
                notes=notes,
            )
        )
        named.add(name)
        current, findings = st, new_f
        _progress(f"named {name}", verbose)
    unexplained = []
    for f in findings[:12]:
        j = f.to_json()
        unexplained.append(
            dict(
                where=f.where,
                rms=j["rms"],
                view=f.view,
                variance_share=f.variance_share,
                log10_p=f.log10_p,
                detail={
                    k: v
                    for k, v in j.items()
                    if k not in ("where", "rms", "view", "variance_share", "log10_p")
                },
            )
        )
    if effects:
        verdict = "missing_physics"
    elif unexplained:
        verdict = "unexplained"
    else:
        verdict = "consistent"
    se0, _ = _cov_se(prep, base, s2)
    status = "ok" if status_ok else "a least-squares solve stopped before converging"
    if throw and not status_ok:
        raise RuntimeError(f"diagnose: {status}")
    diag = Diagnosis(
        verdict=verdict,
        rms_before=math.sqrt(base.ssr / base.resid.size),
        heldout_rms_before=base.heldout_rms,
        rms_final=math.sqrt(current.ssr / current.resid.size),
        heldout_rms_final=current.heldout_rms,
        effects=effects,
        unexplained=unexplained,
        rejected=rejected,
        base=_base_report(prep, base, se0, sigma),
        findings_before=[f.to_json() for f in findings0],
        noise_rad=[float(s) for s in sigma],
        status=status,
        time_s=time.perf_counter() - t0,
        source=str(rec.path) if rec.path is not None else "",
    )
    diag._plot_data = dict(
        prep=prep, base_resid=base.resid, final_resid=current.resid, fold=prep.fold
    )
    return diag


# ----------------------------------------------------------------------------- report


def report_text(d: Diagnosis) -> str:
    """A one-page plain-text report of a diagnosis."""
    u = 1e6
    lines = [
        f"encdesign diagnose: {d.source or 'recording'}",
        f"verdict: {d.verdict}",
        f"base model residual RMS: {d.rms_before * u:.3f} urad fitted, "
        f"{d.heldout_rms_before * u:.3f} urad held out",
        f"noise estimate per head: {', '.join(f'{s * u:.3f}' for s in d.noise_rad)} urad",
    ]
    if d.base.get("unidentifiable"):
        lines.append("unidentifiable from this recording:")
        lines += [f"  - {s}" for s in d.base["unidentifiable"]]
    if d.findings_before:
        lines.append("located in the base residual:")
        for f in d.findings_before[:8]:
            w = f["where"]
            loc = ", ".join(f"{k} {[round(v, 3) for v in w[k]]}" for k in w if w[k])
            lines.append(
                f"  - {f['view']}: {loc}; {100 * f['variance_share']:.1f}% of residual "
                f"variance, log10 p = {f['log10_p']:.1f}"
            )
    for i, e in enumerate(d.effects, 1):
        lines.append(f"effect {i}: {e.name} (dBIC {e.delta_bic:.1f})")
        lines.append(
            f"  residual RMS -> {e.rms_after * u:.3f} urad fitted, "
            f"{e.heldout_rms_after * u:.3f} urad held out"
        )
        lines.append(f"  {e.explanation}")
        for n in e.notes:
            lines.append(f"  note: {n}")
    for r in d.rejected:
        lines.append(f"rejected {r['name']}: {r['reason']}")
    for x in d.unexplained:
        w = x["where"]
        loc = ", ".join(f"{k} {[round(v, 3) for v in w[k]]}" for k in w if w[k])
        lines.append(f"unexplained ({x['view']}): {loc}; rms {x['rms'] * u:.3f} urad")
    lines.append(f"status: {d.status}; {d.time_s:.1f} s")
    return "\n".join(lines) + "\n"


def write_plots(d: Diagnosis, out_dir: str | os.PathLike) -> list[Path]:
    """PNG figures: RMS before/after (fitted, held out), residual spectra before/after,
    per-head residuals before/after. Returns the paths."""
    from ..io._study import new_figure, save_figure
    from ._plots import rms_bars

    out = Path(out_dir)
    pd = d._plot_data
    prep: Prepared = pd["prep"]
    r0, r1 = pd["base_resid"], pd["final_resid"]
    paths = []
    u = 1e6
    fig, ax = new_figure(figsize=(6, 3.5))
    rms_bars(
        ax,
        ["base"] + [f"+ {e.name}" for e in d.effects],
        [d.rms_before] + [e.rms_after for e in d.effects],
        [d.heldout_rms_before] + [e.heldout_rms_after for e in d.effects],
        scale=u,
        fontsize=8,
    )
    ax.axhline(np.mean(d.noise_rad) * u, color="k", ls=":", label="noise estimate")
    ax.set_ylabel("residual RMS (urad)")
    ax.set_title(f"verdict: {d.verdict}")
    ax.legend(fontsize=8)
    paths.append(save_figure(fig, out, "rms_before_after.png"))
    fig, axes = new_figure(2, 1, figsize=(7, 5), sharex=True)
    for ax, res, ttl in ((axes[0], r0, "base model"), (axes[1], r1, "with named effects")):
        for r in range(prep.layout.n_runs):
            rows = np.flatnonzero(prep.run == r)
            t = prep.t[rows]
            dt = (t[-1] - t[0]) / max(rows.size - 1, 1)
            revs = abs(prep.theta[rows][-1] - prep.theta[rows][0]) / (2 * np.pi)
            f_rev = revs / max(t[-1] - t[0], 1e-12)
            X = np.fft.rfft(res[rows] - res[rows].mean(0), axis=0)
            amp = 2 * np.abs(X).mean(1) / rows.size
            fr = np.fft.rfftfreq(rows.size, dt) / max(f_rev, 1e-12)
            ax.semilogy(fr[1:], amp[1:] * u + 1e-6, lw=0.7, label=f"run {prep.run_ids[r]}")
        ax.set_ylabel("amplitude (urad)")
        ax.set_title(f"residual spectrum, {ttl}", fontsize=9)
    axes[1].set_xlabel("shaft order (cycles per revolution)")
    axes[0].legend(fontsize=7)
    paths.append(save_figure(fig, out, "residual_spectra.png"))
    H = prep.layout.n_heads
    fig, axes = new_figure(H, 1, figsize=(7, 1.6 * H + 0.8), sharex=True)
    axes = np.atleast_1d(axes)
    for k in range(H):
        ax = axes[k]
        ax.plot(prep.tau, r0[:, k] * u, lw=0.4, color="tab:red", label="base")
        ax.plot(prep.tau, r1[:, k] * u, lw=0.4, color="tab:blue", label="final")
        ax.set_ylabel(f"h{k} (urad)", fontsize=8)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time, runs end to end (s)")
    paths.append(save_figure(fig, out, "head_residuals.png"))
    return paths
