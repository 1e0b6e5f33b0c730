"""Sums the views share (issue 43): computed once per record or once per residual.

A view's statistics are of two kinds:

* **geometry**: sums of its regressors alone over the kept rows (the Gram matrices of the
  shaft orders' cos / sin, of the order-1 change columns): they depend on the kept rows,
  the angle, the noise weights, not on the residual. :func:`geometry` keeps them across the
  scans of one record (the base fit, each selection round and every detection-bound probe
  scan the same rows), keyed by a fingerprint of what they are computed from
  (:func:`fingerprint`), so a changed angle or set of kept rows computes them anew;
* **linear** in the residual (the regressors' sums with it): within one scan
  (:func:`scanning`, opened by ``_views.locate``) a sum two views need (the ``orders`` and
  ``modulated_orders`` views share their cos / sin sums) is computed once (:func:`linear`).
  The detection bounds scan one residual at many sizes (a bisection): a scan opened with
  ``reuse`` keeps the sums of its residual, computed at unit size, and scales them, so the
  rows are read once per residual (there also the runs' transforms of the ``spectrum`` and
  ``band`` views, as large as the residual: a plain scan does not keep those).

Either way the numbers are those a view computes on its own, up to the order of a sum
(float64 rounding); both are deterministic, so every process of a split diagnosis gets the
same bits.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

GEOMETRY_KEPT = 8
"""Geometry entries kept (the oldest goes first): a few records or angle refinements."""

_GEOM: dict[tuple, Any] = {}


def fingerprint(*arrays) -> str:
    """A digest of ``arrays`` (dtype, shape and bytes): the key of what a sum depends on."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a))
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def geometry(key: tuple, compute: Callable[[], Any]) -> Any:
    """The residual-free sums ``compute()`` under ``key`` (a fingerprint in it), computed
    once while the key is among the last :data:`GEOMETRY_KEPT` used."""
    if key in _GEOM:
        return _GEOM[key]
    value = compute()
    _GEOM[key] = value
    while len(_GEOM) > GEOMETRY_KEPT:
        _GEOM.pop(next(iter(_GEOM)))
    return value


class _Scan:
    """One scan of a residual: its memo of linear sums (at unit size) and its size."""

    def __init__(self, resid: Any, scale: float, memo: dict, reuse: bool):
        self.resid = resid  # held: its identity keys the memo of a reused scan
        self.scale = float(scale)
        self.memo = memo
        self.reuse = reuse


_SCAN: contextvars.ContextVar[_Scan | None] = contextvars.ContextVar(
    "encdesign_views_scan", default=None
)
_LAST: list[_Scan] = []
"""The last scan opened with ``reuse`` (its residual and memo), for the next one."""


@contextlib.contextmanager
def scanning(resid: Any, scale: float = 1.0, reuse: bool = False) -> Iterator[None]:
    """Views run inside share their linear sums (:func:`linear`); with ``reuse``, the memo
    of the last reused scan of the same residual object (``resid``, not mutated between
    scans: the detection bounds' unit residual at several sizes) carries over."""
    memo: dict = {}
    if reuse and _LAST and _LAST[0].resid is resid:
        memo = _LAST[0].memo
    scan = _Scan(resid, scale, memo, reuse)
    if reuse:
        _LAST[:] = [scan]
    token = _SCAN.set(scan)
    try:
        yield
    finally:
        _SCAN.reset(token)


def forget() -> None:
    """Drop the last reused scan's residual and sums (after the detection bounds)."""
    _LAST.clear()


def linear(
    key: tuple, compute: Callable[[], list[np.ndarray]], large: bool = False
) -> list[np.ndarray]:
    """``compute()`` (arrays linear in the residual the views see) once per scan (and per
    residual of a reused scan, scaled to the scan's size); outside a scan, computed.
    ``large`` (arrays of the residual's size): kept only in a reused scan, where the rows
    would otherwise be read once per size (a plain scan computes them where they are
    needed: the peak memory of a long record's scans stays as it was)."""
    scan = _SCAN.get()
    if scan is None or (large and not scan.reuse):
        return compute()
    if key not in scan.memo:
        s = scan.scale
        got = compute()
        scan.memo[key] = got if s == 1.0 else [np.asarray(v) / s for v in got]
        return got
    got = scan.memo[key]
    return got if scan.scale == 1.0 else [v * scan.scale for v in got]


class Whitened:
    """The whitened residual ``resid / sigma`` (n, C), whitened where it is indexed: the
    engine's views read it by row ranges or row indices, so no whitened copy of the whole
    residual is made (``np.asarray`` makes one, for a kind's own views)."""

    def __init__(self, resid: np.ndarray, sigma: np.ndarray, scale: float = 1.0):
        self.resid = resid
        self.inv = 1.0 / np.asarray(sigma, float)[None, :]
        if scale != 1.0:
            self.inv = self.inv * scale
        self.shape = resid.shape
        self.ndim = resid.ndim
        self.dtype = resid.dtype

    def __getitem__(self, idx):
        if isinstance(idx, tuple):
            return (self.resid[idx[0]] * self.inv)[(slice(None), *idx[1:])]
        return self.resid[idx] * self.inv

    def __array__(self, dtype=None, copy=None):
        out = self.resid * self.inv
        return out if dtype is None else out.astype(dtype)

    def __len__(self) -> int:
        return self.shape[0]


__all__ = ["Whitened", "fingerprint", "forget", "geometry", "linear", "scanning"]
