"""The finder engine's data pipeline: lazy row columns, chunked passes, progress, Jacobians."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import encdesign  # noqa: F401  (float64)
from encdesign.diagnose._engine import KeptRows, RowColumns, _valjac_fn
from encdesign.diagnose._multihead import _base_candidate


@pytest.mark.parametrize("all_kept", [True, False])
def test_row_columns_make_the_onehot_and_select_kept_rows(all_kept):
    rng = np.random.default_rng(3)
    n, R = 50, 3
    run = np.sort(rng.integers(0, R, n))
    rows = RowColumns({"t": np.arange(n) * 1e-3, "tau": rng.normal(size=n)}, run, R)
    oh = np.zeros((n, R))
    oh[np.arange(n), run] = 1.0
    assert set(rows) == {"t", "tau", "run_onehot"} and len(rows) == 3
    np.testing.assert_array_equal(rows["run_onehot"], oh)
    np.testing.assert_array_equal(rows.onehot(10, 20), oh[10:20])
    assert "run_onehot" not in dict(rows.stored())
    keep = np.ones(n, bool) if all_kept else rng.uniform(size=n) > 0.3
    kept = KeptRows(rows, keep)
    for k in ("t", "tau", "run_onehot"):
        np.testing.assert_array_equal(kept[k], rows[k][keep])
    full = {k: v for k, v in kept.items()}
    assert set(full) == {"t", "tau", "run_onehot"}
    kept["theta"] = np.zeros(int(keep.sum()))
    assert "theta" in kept and kept["theta"].shape == (int(keep.sum()),)


def test_base_term_jacobian_matches_central_differences_across_runs():
    """The jitted value-and-Jacobian of the base term (every parameter, nonlinear run offsets
    and placements included) against central differences at a point with a disk error:
    an earlier split of the Jacobian into linear / nonlinear halves returned zero rows here."""
    rng = np.random.default_rng(0)
    # the engine's chunk (8192 rows), 4 heads, 4 runs (the last absent from this chunk), 12
    # orders: the shape on which the split Jacobian went wrong
    n, C, R, M = 8192, 4, 4, 12
    run = np.minimum(np.arange(n) // 4000, 2)
    oh = np.zeros((n, R))
    oh[np.arange(n), run] = 1.0
    x = {
        "theta_raw": np.sort(rng.uniform(0, 40, n)),
        "run_onehot": oh,
        "alpha": np.array([0.0, 2.1, 4.2, 0.9]),
    }
    p = {
        "offset_rad": rng.normal(0, 1e-6, (R, C)),
        "fourier_cos_rad": rng.normal(0, 4e-6, M),
        "fourier_sin_rad": rng.normal(0, 4e-6, M),
        "placement_rad": rng.normal(0, 1e-3, C - 1),
        "run_angle_offset_rad": rng.normal(0, 0.5, R - 1),
    }
    cand = _base_candidate(C, R, M)
    pj = {k: jnp.asarray(v) for k, v in p.items()}
    v, J = _valjac_fn(cand)(pj, x)
    np.testing.assert_allclose(np.asarray(v), np.asarray(cand.fn(pj, x)), rtol=0, atol=1e-18)
    h = 1e-6
    for name in ("run_angle_offset_rad", "placement_rad"):
        Jn = np.asarray(J[name]).reshape(n, C, -1)
        for j in range(p[name].size):
            d = np.zeros(p[name].size)
            d[j] = h
            up = {**pj, name: jnp.asarray(p[name] + d.reshape(p[name].shape))}
            dn = {**pj, name: jnp.asarray(p[name] - d.reshape(p[name].shape))}
            fd = (np.asarray(cand.fn(up, x)) - np.asarray(cand.fn(dn, x))) / (2 * h)
            scale = max(np.max(np.abs(fd)), 1e-300)
            assert np.max(np.abs(Jn[:, :, j] - fd)) <= 1e-5 * scale + 1e-14, (name, j)
