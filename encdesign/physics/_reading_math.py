"""The per-reading arithmetic of the kinematic model (:mod:`encdesign.physics._kinematics`):
the one-division arctangent, the grating series by Clenshaw's recurrence, the geometric
error of every head at every angle from the rotated disk frame, and the hand-written reverse
pass of the whole per-reading chain. Angles in rad, lengths in m.

Everything here works on arrays of readings ``(n, H)`` broadcast from per-angle ``(n, 1)``
and per-head ``(1, H)`` inputs; nothing knows about the model's Modules.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, ArrayLike

_GRATING_LOOP_MAX = 64  # orders up to this use Clenshaw's recurrence, beyond: direct sin/cos

# Cephes' arctan (S. L. Moshier): a rational approximation after range reduction, within
# 1 ulp in float64. Written with selects only, so XLA vectorises it (about 3x faster on CPU
# than the library arctan2), and odd in x without abs/sign, so its gradient is right at 0.
_ATAN_P = (
    -8.750608600031904122785e-1,
    -1.615753718733365076637e1,
    -7.500855792314704667340e1,
    -1.228866684490136173410e2,
    -6.485021904942025371773e1,
)
_ATAN_Q = (
    2.485846490142306297962e1,
    1.650270098316988542046e2,
    4.328810604912902668951e2,
    4.853903996359136964868e2,
    1.945506571482613964425e2,
)
_ATAN_MOREBITS = 6.123233995736765886130e-17
_TAN_3PI_8 = 2.41421356237309504880


@jax.custom_jvp
def _atan(x: ArrayLike) -> Array:
    """``arctan(x)``, rad, to 1 ulp (float64), vectorisable and differentiable everywhere
    (:func:`_atan_ratio` with ``b = 1``)."""
    x = jnp.asarray(x)
    return _atan_ratio(x, jnp.ones_like(x))


@_atan.defjvp
def _atan_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    return _atan(x), dx / (1.0 + x * x)


@jax.custom_jvp
def _atan_ratio(a: Array, b: Array) -> Array:
    """``arctan(a / b)``, rad, for ``b > 0`` and ``|a|, |b|`` of order one, with a single
    division per element.

    Cephes' range reduction (``|x| <= 0.66``; ``0.66 < |x| <= tan 3pi/8`` via
    ``(x - 1) / (1 + x)``; beyond via ``-1 / x``) is done on the numerator and denominator
    (``x = a / b`` is never formed), and the rational approximation
    ``atan(r) = r + r z P(z) / Q(z)``, ``z = r^2``, ``r = N / D``, is written homogeneously:
    ``N (Q_h + N^2 P_h) / (D Q_h)`` with ``P_h = D^8 P(z)``, ``Q_h = D^10 Q(z)``, so the one
    division of the whole function is the last one. Within a few ulp of ``arctan`` in
    float64. Its derivative is given in closed form, ``(b da - a db) / (a^2 + b^2)``
    (:func:`_atan_ratio_jvp`), not traced through the selects.
    """
    pos = a > 0.0
    s = jnp.where(pos, 1.0, -1.0)
    sa = s * a  # |a|
    big = sa > _TAN_3PI_8 * b
    mid = (sa > 0.66 * b) & ~big
    n = jnp.where(big, -b, jnp.where(mid, a - s * b, a))
    d = jnp.where(big, a, jnp.where(mid, b + s * a, b))
    y0 = jnp.where(big, s * (jnp.pi / 2), jnp.where(mid, s * (jnp.pi / 4), 0.0))
    corr = jnp.where(big, s * _ATAN_MOREBITS, jnp.where(mid, s * 0.5 * _ATAN_MOREBITS, 0.0))
    n2, d2 = n * n, d * d
    p, q = _ATAN_P, _ATAN_Q
    d4 = d2 * d2
    ph = (((p[0] * n2 + p[1] * d2) * n2 + p[2] * d4) * n2 + p[3] * d4 * d2) * n2 + p[4] * d4 * d4
    qh = (
        (((n2 + q[0] * d2) * n2 + q[1] * d4) * n2 + q[2] * d4 * d2) * n2 + q[3] * d4 * d4
    ) * n2 + q[4] * d4 * d4 * d2
    return y0 + (n * (qh + n2 * ph) / (d * qh) + corr)


@_atan_ratio.defjvp
def _atan_ratio_jvp(primals, tangents):
    (a, b), (da, db) = primals, tangents
    return _atan_ratio(a, b), (b * da - a * db) / (a * a + b * b)


def _grating(sin_rad: Array, cos_rad: Array, s1: Array, c1: Array, psi: Array) -> Array:
    """``sum_j S_j sin(j psi) + C_j cos(j psi)`` given ``sin psi``, ``cos psi`` (rad)."""
    m = sin_rad.shape[0]
    if m == 0:
        return jnp.zeros_like(psi)
    if m > _GRATING_LOOP_MAX:
        j = jnp.arange(1, m + 1, dtype=psi.dtype)
        arg = psi[..., None] * j
        return jnp.sum(sin_rad * jnp.sin(arg) + cos_rad * jnp.cos(arg), axis=-1)
    return _grating_series(sin_rad, cos_rad, s1, c1)


def _instantiate(t: Array | SymbolicZero, primal: Array) -> Array:
    """The tangent ``t`` of ``primal``, zeros of its shape and dtype when symbolic."""
    return jnp.zeros_like(primal) if isinstance(t, SymbolicZero) else t


def _clenshaw(cos_coef: Array, sin_coef: Array, c1: Array, s1: Array) -> Array:
    """``sum_j a_j cos(j psi) + b_j sin(j psi)`` for ``j = 1 … M`` by Clenshaw's recurrence
    (Chebyshev ``T_j`` for the cosines, ``sin psi U_{j-1}`` for the sines), from
    ``c1 = cos psi``, ``s1 = sin psi``: two multiply-adds per order and series."""
    m = cos_coef.shape[0]
    x2 = 2.0 * c1
    bc1 = bc2 = bs1 = bs2 = jnp.zeros_like(c1)
    for j in range(m - 1, 0, -1):  # orders M … 2
        bc1, bc2 = cos_coef[j] + x2 * bc1 - bc2, bc1
        bs1, bs2 = sin_coef[j] + x2 * bs1 - bs2, bs1
    cos_sum = c1 * (cos_coef[0] + x2 * bc1 - bc2) - bc1
    sin_sum = s1 * (sin_coef[0] + x2 * bs1 - bs2)
    return cos_sum + sin_sum


@jax.custom_jvp
def _grating_series(sin_rad: Array, cos_rad: Array, s1: Array, c1: Array) -> Array:
    """``sum_j S_j sin(j psi) + C_j cos(j psi)`` from the unit vector
    ``(c1, s1) = (cos psi, sin psi)``; rad."""
    return _clenshaw(cos_rad, sin_rad, c1, s1)


def _grating_series_jvp(primals, tangents):
    """Closed-form tangent: the series' derivative in ``psi`` is the series of coefficients
    ``j C_j`` (sines, negated) and ``j S_j`` (cosines), and ``d psi = cos psi d(sin psi) -
    sin psi d(cos psi)`` on the unit circle; a coefficient tangent enters linearly.
    Reverse mode then transposes a few multiply-adds per reading."""
    sin_rad, cos_rad, s1, c1 = primals
    d_sin, d_cos, ds1, dc1 = tangents
    j = jnp.arange(1, sin_rad.shape[0] + 1, dtype=s1.dtype)
    g = _clenshaw(cos_rad, sin_rad, c1, s1)
    gp = _clenshaw(j * sin_rad, -j * cos_rad, c1, s1)
    dg = gp * (c1 * _instantiate(ds1, s1) - s1 * _instantiate(dc1, c1))
    if not (isinstance(d_sin, SymbolicZero) and isinstance(d_cos, SymbolicZero)):
        dg = dg + _clenshaw(_instantiate(d_cos, cos_rad), _instantiate(d_sin, sin_rad), c1, s1)
    return g, dg


_grating_series.defjvp(_grating_series_jvp, symbolic_zeros=True)


def _core(frame: tuple[Array, ...]) -> tuple[Array, Array, Array, tuple[Array, ...]]:
    """The per-reading part of the model, ``(n, H)``: the geometric error (rad), the read
    point's ``sin psi``, ``cos psi`` and what the reverse pass needs."""
    nx, ny, nz, lx, ly, lz, cx, cy, cz, ct, st, ux, uy, uz, rx, ry, rz, ca, sa = frame
    # --- ray-plane intersection (seed eq. 36 for a ray from r): i = r + s u with
    # s = (w.n) / (u.n); v = i - c = s u - w is only needed up to a positive factor, so
    # V = |u.n| v = sign(u.n) ((w.n) u - (u.n) w) is used instead (no division)
    wx, wy, wz = cx - rx, cy - ry, cz - rz
    wn = wx * nx + wy * ny + wz * nz
    un_dot = ux * nx + uy * ny + uz * nz
    sg = jnp.where(un_dot < 0.0, -1.0, 1.0)
    wn, un_dot = sg * wn, sg * un_dot
    vx, vy, vz = wn * ux - un_dot * wx, wn * uy - un_dot * wy, wn * uz - un_dot * wz
    # --- signed angle psi from v to the index line about n
    crx, cry, crz = vy * lz - vz * ly, vz * lx - vx * lz, vx * ly - vy * lx
    sin_part = crx * nx + cry * ny + crz * nz  # |V| sin(psi)
    cos_part = vx * lx + vy * ly + vz * lz  # |V| cos(psi)
    rho2 = sin_part * sin_part + cos_part * cos_part
    rho = jnp.sqrt(rho2)
    # one division for both components; written rho / rho^2, not 1 / rho: XLA rewrites
    # 1 / sqrt(x) into rsqrt, whose float64 CPU code runs the whole kernel at 22 vs 61 M/s
    inv_rho = rho / rho2
    s1, c1 = sin_part * inv_rho, cos_part * inv_rho
    # geometric error psi - (theta - alpha_k), wrapped to (-pi, pi): rotate (cos psi, sin psi)
    # back by theta - alpha_k, whose sine and cosine need no further trigonometry
    cd, sd = ct * ca + st * sa, st * ca - ct * sa  # cos, sin of (theta - alpha_k)
    # half-angle form of atan2 for unit vectors: phi = 2 atan(sin phi / (1 + cos phi)),
    # exact for |phi| < pi (a head 180 deg off is not an encoder)
    a_, b_ = s1 * cd - c1 * sd, 1.0 + c1 * cd + s1 * sd
    geom = 2.0 * _atan_ratio(a_, b_)
    return (
        geom,
        s1,
        c1,
        (sg, wx, wy, wz, un_dot, wn, vx, vy, vz, crx, cry, crz, inv_rho, cd, sd, a_, b_),
    )


def _angle_frame(consts: tuple[Array, ...], theta: Array, time: Array | None) -> tuple[Array, ...]:
    """The disk frame rotated to every shaft angle ``theta (n,)`` rad (times ``(n,)`` s):
    normal ``n``, index line ``l`` and centre ``c`` (unit vectors; m) and ``cos``/``sin`` of
    ``theta``, each ``(n, 1)``, from the design constants of ``_kinematics._design``."""
    n0x, n0y, n0z, l0x, l0y, l0z, c0x, c0y, amp, ratio, phase0, freq, ax_c, ax_s = consts
    th = theta[:, None]
    ct, st = jnp.cos(th), jnp.sin(th)
    nx, ny, nz = ct * n0x - st * n0y, st * n0x + ct * n0y, jnp.broadcast_to(n0z, th.shape)
    lx, ly, lz = ct * l0x - st * l0y, st * l0x + ct * l0y, jnp.broadcast_to(l0z, th.shape)
    phase = _phase(ratio, phase0, freq, th, time)
    cx = ct * c0x - st * c0y + amp * jnp.cos(phase)
    cy = st * c0x + ct * c0y + amp * jnp.sin(phase)
    if ax_c.shape[0]:
        ca_j, sa_j = _axial_basis(theta, ax_c.shape[0])
        cz = (ca_j @ ax_c + sa_j @ ax_s)[:, None]
    else:
        cz = jnp.zeros_like(th)
    return nx, ny, nz, lx, ly, lz, cx, cy, cz, ct, st


def _phase(ratio: Array, phase0: Array, freq: Array, th: Array, time: Array | None) -> Array:
    """Phase of the runout, rad, ``(n, 1)``."""
    phase = ratio * th + phase0
    return phase if time is None else phase + 2 * jnp.pi * freq * time[:, None]


def _axial_basis(theta: Array, k: int) -> tuple[Array, Array]:
    """``cos(j theta)``, ``sin(j theta)`` for ``j = 1 ... k``, ``(n, k)``."""
    arg = theta[:, None] * jnp.arange(1, k + 1, dtype=theta.dtype)
    return jnp.cos(arg), jnp.sin(arg)


def _broadcast_frame(per_angle: tuple[Array, ...], per_head: tuple[Array, ...]) -> tuple:
    """Per-angle ``(n, 1)`` and per-head ``(H,)`` arrays as the frame of :func:`_core`."""
    n, h = per_angle[0].shape[0], per_head[0].shape[-1]
    return (
        *(jnp.broadcast_to(x, (n, 1)) for x in per_angle),
        *(jnp.broadcast_to(x, (1, h)) for x in per_head),
    )


@jax.custom_vjp
def _sums(xs: tuple[Array, ...]) -> tuple[Array, ...]:
    """``sum(x, axis=0)`` of every ``x`` (equal shapes) as ONE variadic reduction: XLA
    computes what the summands share once per element instead of once per summand or
    stored (the reverse pass below has ~40 summands from the same per-reading values)."""
    zero = jnp.zeros((), xs[0].dtype)
    return tuple(
        jax.lax.reduce(
            tuple(xs), (zero,) * len(xs), lambda a, b: tuple(u + v for u, v in zip(a, b)), (0,)
        )
    )


def _sums_fwd(xs):
    return _sums(xs), xs[0].shape


def _sums_bwd(shape, bars):
    return (tuple(jnp.broadcast_to(b, shape) for b in bars),)


_sums.defvjp(_sums_fwd, _sums_bwd)


@jax.custom_vjp
def _readings(consts, per_head, theta, time, sin_rad: Array, cos_rad: Array) -> Array:
    """Head errors ``(n, H)``, rad: :func:`_core` on the frame of :func:`_angle_frame` plus
    the grating series (orders ``1 ... M``, ``M <= _GRATING_LOOP_MAX``), with a
    hand-written reverse pass (:func:`_readings_bwd`): every per-reading cotangent is formed
    and reduced straight to the design's constants and heads in one variadic reduction over
    the angles, instead of XLA's transposition of each broadcast (about 70 reductions and
    60 stored per-reading arrays per design)."""
    frame = _broadcast_frame(_angle_frame(consts, theta, time), per_head)
    geom, s1, c1, _ = _core(frame)
    return geom + _clenshaw(cos_rad, sin_rad, c1, s1) if sin_rad.shape[0] else geom


def _readings_fwd(consts, per_head, theta, time, sin_rad, cos_rad):
    out = _readings(consts, per_head, theta, time, sin_rad, cos_rad)
    return out, (consts, per_head, theta, time, sin_rad, cos_rad)


def _readings_bwd(res, e_bar):
    consts, per_head, theta, time, sin_rad, cos_rad = res
    n0x, n0y, n0z, l0x, l0y, l0z, c0x, c0y, amp, ratio, phase0, freq, ax_c, ax_s = consts
    per_angle = _angle_frame(consts, theta, time)
    frame = _broadcast_frame(per_angle, per_head)
    nx, ny, nz, lx, ly, lz, cx, cy, cz, ct, st, ux, uy, uz, rx, ry, rz, ca, sa = frame
    geom, s1, c1, aux = _core(frame)
    sg, wx, wy, wz, un_dot, wn, vx, vy, vz, crx, cry, crz, inv_rho, cd, sd, a_, _ = aux
    m, k = sin_rad.shape[0], ax_c.shape[0]
    j = jnp.arange(1, m + 1, dtype=s1.dtype)
    gp = _clenshaw(j * sin_rad, -j * cos_rad, c1, s1) if m else jnp.zeros_like(s1)  # dg/dpsi
    # geom = atan2(S, C) of the unit vector (C, S) = (c1 cd + s1 sd, s1 cd - c1 sd):
    # d geom = C dS - S dC, no division
    big_c, big_s = c1 * cd + s1 * sd, a_
    s_bar, c_bar = e_bar * big_c, -e_bar * big_s
    s1_bar = s_bar * cd + c_bar * sd + e_bar * gp * c1
    c1_bar = -s_bar * sd + c_bar * cd - e_bar * gp * s1
    cd_bar, sd_bar = s_bar * s1 + c_bar * c1, -s_bar * c1 + c_bar * s1
    # s1, c1 = (sin_part, cos_part) / rho
    t = s1 * s1_bar + c1 * c1_bar
    sp_bar, cp_bar = (s1_bar - s1 * t) * inv_rho, (c1_bar - c1 * t) * inv_rho
    # sin_part = (V x l) . n, cos_part = V . l
    crx_b, cry_b, crz_b = sp_bar * nx, sp_bar * ny, sp_bar * nz
    vx_b = ly * crz_b - lz * cry_b + cp_bar * lx
    vy_b = lz * crx_b - lx * crz_b + cp_bar * ly
    vz_b = lx * cry_b - ly * crx_b + cp_bar * lz
    lx_b = cry_b * vz - crz_b * vy + cp_bar * vx
    ly_b = crz_b * vx - crx_b * vz + cp_bar * vy
    lz_b = crx_b * vy - cry_b * vx + cp_bar * vz
    # V = wn u - un w (both already times sign(u.n)); wn = sg w.n, un = sg u.n
    wn_b = sg * (vx_b * ux + vy_b * uy + vz_b * uz)
    un_b = -sg * (vx_b * wx + vy_b * wy + vz_b * wz)
    wx_b = -un_dot * vx_b + wn_b * nx
    wy_b = -un_dot * vy_b + wn_b * ny
    wz_b = -un_dot * vz_b + wn_b * nz
    ux_b, uy_b, uz_b = wn * vx_b + un_b * nx, wn * vy_b + un_b * ny, wn * vz_b + un_b * nz
    nx_b = sp_bar * crx + wn_b * wx + un_b * ux
    ny_b = sp_bar * cry + wn_b * wy + un_b * uy
    nz_b = sp_bar * crz + wn_b * wz + un_b * uz
    # the per-angle frame is linear in the design constants: reduce straight onto them
    phase = _phase(ratio, phase0, freq, theta[:, None], time)
    cph, sph = jnp.cos(phase), jnp.sin(phase)
    ph_b = amp * (wy_b * cph - wx_b * sph)
    const_terms = [
        nx_b * ct + ny_b * st, ny_b * ct - nx_b * st, nz_b,
        lx_b * ct + ly_b * st, ly_b * ct - lx_b * st, lz_b,
        wx_b * ct + wy_b * st, wy_b * ct - wx_b * st,
        wx_b * cph + wy_b * sph, ph_b * theta[:, None], ph_b,
    ]  # fmt: skip
    if time is not None:
        const_terms.append(ph_b * (2 * jnp.pi) * time[:, None])
    ax_terms = []
    if k:
        ca_j, sa_j = _axial_basis(theta, k)
        ax_terms = [wz_b * ca_j[:, i : i + 1] for i in range(k)]
        ax_terms += [wz_b * sa_j[:, i : i + 1] for i in range(k)]
    sj, cj, sins, coss = s1, c1, [], []  # grating coefficients: e_bar sin(j psi), cos(j psi)
    for _ in range(m):
        sins.append(e_bar * sj)
        coss.append(e_bar * cj)
        sj, cj = sj * c1 + cj * s1, cj * c1 - sj * s1
    grating_terms = sins + coss
    ca_b, sa_b = cd_bar * ct + sd_bar * st, cd_bar * st - sd_bar * ct  # cos, sin(theta - alpha)
    heads = [ux_b, uy_b, uz_b, -wx_b, -wy_b, -wz_b, ca_b, sa_b]
    sums = list(_sums(tuple(const_terms + ax_terms + grating_terms + heads)))
    groups = []  # the sums split back into their groups, in the order above
    for size in (len(const_terms), len(ax_terms), len(grating_terms)):
        groups.append([jnp.sum(x) for x in sums[:size]])
        sums = sums[size:]
    (c_bar, a_bar, g_bar), head_sums = groups, sums
    freq_bar = c_bar[11] if time is not None else jnp.zeros_like(freq)
    consts_bar = (
        *c_bar[:11], freq_bar,
        jnp.stack(a_bar[:k]) if k else jnp.zeros_like(ax_c),
        jnp.stack(a_bar[k:]) if k else jnp.zeros_like(ax_s),
    )  # fmt: skip
    sin_bar = jnp.stack(g_bar[:m]) if m else jnp.zeros_like(sin_rad)
    cos_bar = jnp.stack(g_bar[m:]) if m else jnp.zeros_like(cos_rad)
    head_bar = tuple(x.reshape(p.shape) for x, p in zip(head_sums, per_head, strict=True))
    # the shaft angles and times (inputs, rarely differentiated: XLA drops these when unused)
    ct_b = cd_bar * ca - sd_bar * sa + nx_b * n0x + ny_b * n0y + lx_b * l0x + ly_b * l0y
    ct_b = ct_b + wx_b * c0x + wy_b * c0y
    st_b = cd_bar * sa + sd_bar * ca - nx_b * n0y + ny_b * n0x - lx_b * l0y + ly_b * l0x
    st_b = st_b - wx_b * c0y + wy_b * c0x
    th_b = ct * st_b - st * ct_b + ratio * ph_b
    if k:
        jj = jnp.arange(1, k + 1, dtype=theta.dtype)
        th_b = th_b + wz_b * ((ca_j * jj) @ ax_s - (sa_j * jj) @ ax_c)[:, None]
    theta_bar = jnp.sum(th_b, axis=1)
    time_bar = None if time is None else jnp.sum(ph_b, axis=1) * (2 * jnp.pi) * freq
    bars = (consts_bar, head_bar, theta_bar, time_bar)
    res_in = (consts, per_head, theta, time)
    bars = jax.tree.map(
        lambda b, x: None if b is None else _unvary_like(b, x),
        bars,
        res_in,
        is_leaf=lambda x: x is None,
    )
    return (*bars, _unvary_like(sin_bar, sin_rad), _unvary_like(cos_bar, cos_rad))


def _unvary_like(bar: Array, x: Array) -> Array:
    """Inside ``shard_map``: the cotangent of an input that does not vary over a mesh axis
    (the shaft angles, replicated) is summed over that axis, as JAX's own transposition does."""
    extra = tuple(sorted(_varying(bar) - _varying(x)))
    return jax.lax.psum(bar, extra) if extra else bar


def _varying(x: Array) -> frozenset:
    """The mesh axes ``x`` varies over inside ``shard_map`` (empty outside)."""
    aval = jax.typeof(x)
    mat = getattr(aval, "mat", None)  # JAX >= 0.10: manual axis type; earlier: .vma
    return frozenset(getattr(mat, "varying", None) or getattr(aval, "vma", None) or ())


_readings.defvjp(_readings_fwd, _readings_bwd)
