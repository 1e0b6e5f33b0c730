"""Shape annotations of the public physics signatures are true and checked: jaxtyping with
beartype accepts the documented shapes and refuses axes that disagree (the same check the
pytest hook in ``pyproject.toml`` runs on every call in the tests)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from beartype import beartype
from jaxtyping import TypeCheckError, jaxtyped

from encdesign.physics import _kinematics as kin
from encdesign.physics import _theorem as th


def _checked(fn):
    return jaxtyped(typechecker=beartype)(fn)


def test_theorem_shapes_accept_documented_and_refuse_disagreeing_axes():
    errors = jnp.zeros((5, 3))
    assert _checked(th.averaged_error)(errors, [1.0, 1.0, 2.0]).shape == (5,)
    with pytest.raises(TypeCheckError):  # 4 weights for 3 heads
        _checked(th.averaged_error)(errors, np.ones(4))
    assert _checked(th.surviving_orders)(np.array([0.0, 2.0, 4.0]), 6).shape == (6,)
    with pytest.raises(TypeCheckError):  # head azimuths must be one axis
        _checked(th.surviving_orders)(np.zeros((2, 2)), 6)


def test_kinematics_shapes_scalar_and_vector_angles():
    m = kin.make_model(0.02, [0.0, 2.0, 4.0], grating_sin_rad=[1e-6])
    f = _checked(kin.head_errors)
    assert f(m, 0.3).shape == (3,)
    assert f(m, np.linspace(0, 1, 7), np.linspace(0, 1, 7)).shape == (7, 3)
    with pytest.raises(TypeCheckError):  # angles must be a scalar or one axis of floats
        f(m, np.zeros(4, dtype=np.int64))
