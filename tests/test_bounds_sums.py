"""Issue 43: the detection bounds' one pass over the rows (``_Bench.prepare``, the sums of
``engine._bounds_sums``) against each probe's own pass (the path before it, still taken by a
probe not prepared): the same bounds to rounding.

Training seed 1531 (``benchmarks/SEEDS.md``: the detection-bound tests' geometries)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from encdesign.diagnose import diagnose


def _close(a, b, where: str = "") -> list[str]:
    """Paths where the documents ``a`` and ``b`` differ (numbers beyond 1e-9 relative)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{where}: keys"]
        return [d for k in a for d in _close(a[k], b[k], f"{where}.{k}")]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: lengths"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _close(x, y, f"{where}[{i}]")]
    if isinstance(a, float) and isinstance(b, float):
        return [] if abs(a - b) <= 1e-9 * max(abs(a), abs(b)) else [f"{where}: {a} vs {b}"]
    return [] if a == b else [f"{where}: {a!r} vs {b!r}"]


def test_channel_products_equal_the_whole_matrices():
    from encdesign.diagnose.engine._bounds_sums import _channel_products

    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(50, 3, 4)), rng.normal(size=(50, 3, 2))
    w = np.array([1.0, 4.0, 0.25])
    out, out_u = np.zeros((4, 2)), np.zeros((4, 2))
    _channel_products(A, B, w, out, out_u)
    np.testing.assert_allclose(out, A.reshape(-1, 4).T @ B.reshape(-1, 2), rtol=1e-13)
    Bu = (B / w[None, :, None]).reshape(-1, 2)
    np.testing.assert_allclose(out_u, A.reshape(-1, 4).T @ Bu, rtol=1e-13)
    q, qu = np.zeros(2), np.zeros(2)
    _channel_products(B, B, w, q, qu, diagonal=True)
    np.testing.assert_allclose(q, np.sum(B * B, axis=(0, 1)), rtol=1e-13)
    np.testing.assert_allclose(qu, np.sum(B * B / w[None, :, None], axis=(0, 1)), rtol=1e-13)


def test_prepared_bounds_equal_each_probe_on_its_own(monkeypatch):
    """Every probe of a record with a named effect prepared in the shared pass (norm, own
    RMS and normal equations from its sums) against every probe making its own pass: the
    same entries, numbers to 1e-9 relative (rounding: sums in another order)."""
    import encdesign.diagnose.engine._bounds as bounds

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from detection_bounds import vibration_record

    _, rate = vibration_record(1531, 1531, 0.0, 1, None)
    rec = vibration_record(1531, 1531, 3e-5, 1, 0.23 * rate)[0]  # far above the noise
    used: list[int] = []
    got: list[list] = []  # each probe's noncentrality, parameters and own RMS
    probe = bounds._Bench.probe

    def counted(self, cand, pr):
        used.append(id(pr) in self._pre)
        out = probe(self, cand, pr)
        got.append(None if out is None else [out[0], out[1], out[3]])
        return out

    monkeypatch.setattr(bounds._Bench, "probe", counted)
    shared = diagnose(rec).doc
    assert len(used) >= 4 and all(used), used
    monkeypatch.setattr(bounds._Bench, "prepare", lambda self, probes: None)
    first = list(got)
    used.clear()
    got.clear()
    alone = diagnose(rec).doc
    assert len(used) >= 4 and not any(used), used
    assert [e["name"] for e in shared["effects"]] == ["vibration"]
    assert any(e["bound"] is not None for e in shared["detection_bounds"])
    assert not _close(first, got)
    assert not _close(shared["detection_bounds"], alone["detection_bounds"])
