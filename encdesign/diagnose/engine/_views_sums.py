"""Sums the views share (issue 43): computed once per record or once per residual.

A view's statistics are of two kinds:

* **geometry**: sums of its regressors alone over the kept rows (the Gram matrices of the
  shaft orders' cos / sin, of the order-1 change columns): they depend on the kept rows,
  the angle, the noise weights, not on the residual. :func:`geometry` keeps them across the
  scans of one record (the base fit, each selection round and every detection-bound probe
  scan the same rows), keyed by a fingerprint of what they are computed from
  (:func:`fingerprint`), so a changed angle or set of kept rows computes them anew;
* **linear** in the residual (the regressors' sums with it): within one scan
  (:meth:`ViewSums.scanning`, opened by ``_views.locate``) a sum two views need (the ``orders`` and
  ``modulated_orders`` views share their cos / sin sums) is computed once (:func:`linear`).
  The detection bounds scan one residual at many sizes (a bisection): a scan opened with
  ``reuse`` keeps the sums of its residual, computed at unit size, and scales them, so the
  rows are read once per residual (there also the runs' transforms of the ``spectrum`` and
  ``band`` views, as large as the residual: a plain scan does not keep those).

Either way the numbers are those a view computes on its own, up to the order of a sum
(float64 rounding); both are deterministic, so every process of a split diagnosis gets the
same bits.

Both are kept by the record's :class:`ViewSums` (``Prepared.view_sums``, made with the
prepared record), never in this module: two diagnoses in one process share nothing.
"""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

GEOMETRY_KEPT = 8
"""Geometry entries kept (the oldest goes first): a few records or angle refinements."""


def fingerprint(*arrays) -> str:
    """A digest of ``arrays`` (dtype, shape and bytes): the key of what a sum depends on."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a))
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


class _Scan:
    """One scan of a residual: its memo of linear sums (at unit size) and its size."""

    def __init__(self, resid: Any, scale: float, memo: dict, reuse: bool):
        self.resid = resid  # held: its identity keys the memo of a reused scan
        self.scale = float(scale)
        self.memo = memo
        self.reuse = reuse


class ViewSums:
    """The sums one diagnosis keeps across its scans (``Prepared.view_sums``, one per
    prepared record): the geometry entries (:meth:`geometry`), the scan open now
    (:meth:`scanning`) and the last scan opened with ``reuse`` (its residual and memo, for
    the next one). Nothing is shared between diagnoses: two records diagnosed in one
    process (or in two threads) each have their own."""

    def __init__(self) -> None:
        self._geom: dict[tuple, Any] = {}
        self._scan: _Scan | None = None
        self._last: _Scan | None = None

    def geometry(self, key: tuple, compute: Callable[[], Any]) -> Any:
        """The residual-free sums ``compute()`` under ``key`` (a fingerprint in it),
        computed once while the key is among the last :data:`GEOMETRY_KEPT` used."""
        if key in self._geom:
            return self._geom[key]
        value = compute()
        self._geom[key] = value
        while len(self._geom) > GEOMETRY_KEPT:
            self._geom.pop(next(iter(self._geom)))
        return value

    @contextlib.contextmanager
    def scanning(self, resid: Any, scale: float = 1.0, reuse: bool = False) -> Iterator[None]:
        """Views run inside share their linear sums (:meth:`linear`); with ``reuse``, the
        memo of the last reused scan of the same residual object (``resid``, not mutated
        between scans: the detection bounds' unit residual at several sizes) carries
        over."""
        memo: dict = {}
        last = self._last
        if reuse and last is not None and last.resid is resid:
            memo = last.memo
        scan = _Scan(resid, scale, memo, reuse)
        if reuse:
            self._last = scan
        outer, self._scan = self._scan, scan
        try:
            yield
        finally:
            self._scan = outer

    def forget(self) -> None:
        """Drop the last reused scan's residual and sums (after the detection bounds)."""
        self._last = None

    def linear(
        self, key: tuple, compute: Callable[[], list[np.ndarray]], large: bool = False
    ) -> list[np.ndarray]:
        """``compute()`` (arrays linear in the residual the views see) once per scan (and
        per residual of a reused scan, scaled to the scan's size); outside a scan,
        computed. ``large`` (arrays of the residual's size): kept only in a reused scan,
        where the rows would otherwise be read once per size (a plain scan computes them
        where they are needed: the peak memory of a long record's scans stays as it
        was)."""
        scan = self._scan
        if scan is None or (large and not scan.reuse):
            return compute()
        if key not in scan.memo:
            s = scan.scale
            got = compute()
            scan.memo[key] = got if s == 1.0 else [np.asarray(v) / s for v in got]
            return got
        got = scan.memo[key]
        return got if scan.scale == 1.0 else [v * scan.scale for v in got]


def sums_of(prep: Any) -> ViewSums:
    """The :class:`ViewSums` of a prepared record (``prep.view_sums``)."""
    got = getattr(prep, "view_sums", None)
    if not isinstance(got, ViewSums):
        raise TypeError(
            f"sums_of: the prepared record {type(prep).__name__} has no view_sums "
            f"(a ViewSums), got {type(got).__name__}"
        )
    return got


def geometry(prep: Any, key: tuple, compute: Callable[[], Any]) -> Any:
    """:meth:`ViewSums.geometry` of ``prep``'s sums."""
    return sums_of(prep).geometry(key, compute)


def linear(
    prep: Any, key: tuple, compute: Callable[[], list[np.ndarray]], large: bool = False
) -> list[np.ndarray]:
    """:meth:`ViewSums.linear` of ``prep``'s sums."""
    return sums_of(prep).linear(key, compute, large)


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


__all__ = ["ViewSums", "Whitened", "fingerprint", "geometry", "linear", "sums_of"]
