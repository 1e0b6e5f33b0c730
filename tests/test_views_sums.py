"""The sums the views share (issue 43, ``engine._views_sums`` and ``engine._views_orders``):
the shaft orders' sums of one pass equal the direct ones, their geometry is kept across
residuals, and a residual scanned at several sizes reuses its sums scaled; the sums are kept
by each prepared record (``Prepared.view_sums``), never in the module."""

from __future__ import annotations

import types
import typing

import numpy as np

from encdesign.diagnose import FinderSettings
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.engine import _views_sums
from encdesign.diagnose.engine._views_orders import harmonics, order_scan
from encdesign.diagnose.engine._views_sums import ViewSums, Whitened, linear
from tests.helpers import late_stamps_record


class _Rows(dict):
    def take(self, name, idx):
        return self[name][idx]

    def column(self, name, a, b):
        return self[name][a:b]


def _prep(n: int, C: int = 2, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    th = 2 * np.pi * 1.3 * t + rng.uniform(0, 2 * np.pi)
    keep = rng.random(n) > 0.1
    return types.SimpleNamespace(
        settings=FinderSettings(),
        keep=keep,
        rows=_Rows(t=t, tau=t, theta=th),
        run=np.zeros(n, int),
        sigma=np.full(C, 0.5),
        view_sums=ViewSums(),
    )


def test_harmonics_are_the_cos_and_sin_of_the_orders():
    th = np.linspace(-40.0, 900.0, 5001)
    c, s = harmonics(th, 30)
    m = np.arange(1, 31)[:, None]
    assert np.allclose(c, np.cos(m * th), atol=1e-11, rtol=0)
    assert np.allclose(s, np.sin(m * th), atol=1e-11, rtol=0)


def test_order_sums_equal_the_direct_sums_and_keep_their_geometry():
    """One pass gives the whole record's sums (the ``orders`` view's) as the totals over the
    change-point segments; a second residual on the same rows reuses the Gram sums (the
    same arrays) and gets its own residual sums."""
    n, M = 3000, 9
    prep = _prep(n)
    rng = np.random.default_rng(1)
    r1, r2 = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    got = order_scan(prep, r1, M, [0, 1])
    k = np.flatnonzero(prep.keep)
    ang = prep.rows["theta"][k][:, None] * np.arange(1, M + 1)[None, :]
    c, s = np.cos(ang), np.sin(ang)
    Scc, Sss, Scs, Bc, Bs = got.totals()
    assert got.n == k.size
    np.testing.assert_allclose(Scc, (c * c).sum(0), rtol=1e-10)
    np.testing.assert_allclose(Scs, (c * s).sum(0), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Bc, c.T @ r1[k], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Bs, s.T @ r1[k], rtol=1e-9, atol=1e-9)
    again = order_scan(prep, r2, M, [0, 1])
    assert again.S is got.S  # the geometry, kept
    np.testing.assert_allclose(again.totals()[3], c.T @ r2[k], rtol=1e-9, atol=1e-9)
    # other kept rows: other geometry
    prep.keep = prep.keep.copy()
    prep.keep[:100] = False
    other = order_scan(prep, r1, M, [0, 1])
    assert other.S is not got.S and other.n == got.n - int((got.kidx < 100).sum())


def test_a_residual_scanned_at_several_sizes_reuses_its_sums_scaled():
    """Within a scan a sum is computed once; a reused scan of the same residual at another
    size returns it scaled (no pass), a new residual computes its own."""
    n = 2000
    prep = _prep(n, seed=2)
    resid = np.random.default_rng(3).normal(size=(n, 2))
    calls = []

    def sums(rw):
        def compute():
            calls.append(1)
            return [np.asarray(rw[np.arange(n)]).sum(0)]

        return linear(prep, ("test",), compute)[0]

    scanning = prep.view_sums.scanning
    with scanning(resid, 1.0, reuse=True):
        one = sums(Whitened(resid, prep.sigma))
        assert np.array_equal(sums(Whitened(resid, prep.sigma)), one) and len(calls) == 1
    with scanning(resid, 3.0, reuse=True):
        three = sums(Whitened(resid, prep.sigma, 3.0))
    assert len(calls) == 1
    np.testing.assert_allclose(three, 3.0 * one, rtol=1e-14)
    with scanning(resid.copy(), 3.0, reuse=True):  # another residual object
        sums(Whitened(resid, prep.sigma, 3.0))
    assert len(calls) == 2
    prep.view_sums.forget()
    sums(Whitened(resid, prep.sigma))  # outside a scan: computed each time
    assert len(calls) == 3


def _without_times(doc: dict) -> dict:
    """The document but its times (the report's last line, ``status: ok; 0.4 s``, too)."""
    out = {k: v for k, v in doc.items() if k not in ("time_s", "timings_s", "timings_cpu_s")}
    out["report"] = [x for x in doc["report"].splitlines() if not x.startswith("status:")]
    return out


def test_two_diagnoses_in_one_process_share_no_sums():
    """A record diagnosed after another gives the document it gives first in the process:
    each diagnosis keeps its own sums (``Prepared.view_sums``), none carries over."""
    a, _ = late_stamps_record(7450, n_gaps=3)  # 1710 and 1245 rows: one chunk size
    b, _ = late_stamps_record(7451, n_gaps=1)
    da = diagnose(a)
    db = diagnose(b)
    again = diagnose(a)
    assert _without_times(again.doc) == _without_times(da.doc)
    assert _without_times(db.doc) != _without_times(da.doc)  # another record
    assert da.plot_data is not None and db.plot_data is not None and again.plot_data is not None
    sa, sb = da.plot_data.prep.view_sums, db.plot_data.prep.view_sums
    assert sa is not sb and sa is not again.plot_data.prep.view_sums
    assert sa._geom and sb._geom and not set(sa._geom) & set(sb._geom)


def test_the_module_keeps_no_state():
    """No mutable object at the module's top level (a dict, a list, a context variable of
    scans): only modules, functions, classes and immutable constants."""
    constants = (int, float, str, bytes, bool, tuple, frozenset, type(None))
    for name, v in vars(_views_sums).items():
        if name.startswith("__") or type(v).__module__ == "__future__":
            continue
        ok = isinstance(v, (types.ModuleType, types.FunctionType, type, *constants))
        assert ok or v is typing.Any, (name, type(v))


def test_the_multihead_views_scan_the_residual_without_a_whitened_copy(monkeypatch):
    """Issue 43 (peak memory): the multihead kind's own views read the residual by rows
    (``KindView.rows``), so a scan makes no whitened copy of the whole residual (``8 C``
    bytes a row; on main one per scan), and they find what they find on the copy, to the
    last bit."""
    import dataclasses

    from encdesign.diagnose.engine._views import locate
    from encdesign.diagnose.kinds.multihead import _multihead
    from tests.test_diagnose import _bench

    copies: list[tuple] = []
    as_array = Whitened.__array__

    def counted(self, dtype=None, copy=None):
        copies.append(self.shape)
        return as_array(self, dtype, copy)

    monkeypatch.setattr(Whitened, "__array__", counted)
    rec, _ = _bench(6, vibration_hz=37.0)
    d = diagnose(rec)
    assert [e["name"] for e in d.effects] == ["vibration"]
    assert copies == []
    prep, resid = d.plot_data.prep, d.plot_data.base_resid
    views = _multihead.MULTIHEAD_VIEWS
    mine = [v for v in views if not isinstance(v, str)]
    assert mine and all(v.rows for v in mine)
    on_copy = tuple(v if isinstance(v, str) else dataclasses.replace(v, rows=False) for v in views)

    def found(vs):
        s = float(np.mean(prep.sigma))
        return [f.to_json(s) for f in locate(prep, resid, vs, 12)]

    by_rows = found(views)
    assert copies == []
    assert found(on_copy) == by_rows
    assert copies  # (the copy was made there)
