"""The QR products of the multihead runout and vibration-start searches (issue 43)."""

from __future__ import annotations

import numpy as np

from encdesign.diagnose.kinds.multihead._runout import _gain, _qr_apply
from encdesign.diagnose.kinds.multihead._vibration_doubt import _line_cols


def test_qr_applied_by_its_reflectors_equals_the_formed_q():
    """``_qr_apply``: LAPACK's ``R`` and ``Q^T Y`` as ``numpy.linalg.qr`` forms them, on a
    tall block with a zero column (a run absent from a row group), a short block and a
    square one; the gain is ``|Q^T Y|^2``."""
    rng = np.random.default_rng(7965)
    for n, q in ((5000, 10), (7, 12), (12, 12), (300, 1)):
        X = rng.normal(size=(n, q))
        X[:, q // 2] = 0.0
        Y = rng.normal(size=(n, 4)) + X[:, :1]
        R, QtY = _qr_apply(X, Y)
        Q0, R0 = np.linalg.qr(X)
        assert R.shape == R0.shape and QtY.shape == (R0.shape[0], 4)
        np.testing.assert_allclose(R, R0, rtol=1e-13, atol=1e-13 * np.abs(R0).max())
        want = Q0.T @ Y
        np.testing.assert_allclose(QtY, want, rtol=0, atol=1e-13 * np.abs(want).max())
        if n > q:
            assert np.isclose(_gain(Y, X), float(np.sum(want**2)), rtol=1e-13, atol=0)
    assert _gain(np.ones((3, 2)), np.ones((3, 5))) == 0.0  # fewer rows than columns


def test_line_columns_written_beside_more_columns():
    """``_line_cols`` with ``more``: the line's columns per run, then ``more``, the same
    numbers as joined after."""
    rng = np.random.default_rng(7966)
    n = 500
    t = np.sort(rng.uniform(0, 4, n))
    oh = np.zeros((n, 3))
    oh[np.arange(n), (t // 1.5).astype(int)] = 1.0
    more = rng.normal(size=(n, 2))
    c, s = np.cos(2 * np.pi * 31.0 * t), np.sin(2 * np.pi * 31.0 * t)
    want = np.concatenate([c[:, None] * oh, s[:, None] * oh], 1)
    np.testing.assert_array_equal(_line_cols(t, oh, 31.0), want)
    np.testing.assert_array_equal(_line_cols(t, oh, 31.0, more), np.concatenate([want, more], 1))
