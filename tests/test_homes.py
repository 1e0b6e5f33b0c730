"""``engine._homes``: each candidate's home process, dealt by the size of its Jacobian
program (issue 43)."""

from __future__ import annotations

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np

from encdesign.diagnose.engine._candidates import Candidate, Param
from encdesign.diagnose.engine._homes import homes, program_size


class _Rows:
    def __init__(self, cols: dict[str, np.ndarray]):
        self.cols = cols

    def names(self) -> list[str]:
        return list(self.cols)

    def column(self, k: str, a: int, b: int) -> np.ndarray:
        return self.cols[k][a:b]


def _prep():
    rows = _Rows({"theta": np.zeros(5), "reading": np.zeros((5, 2))})
    return SimpleNamespace(
        n_channels=2, ctx=SimpleNamespace(n_runs=1), rows=rows, consts={"alpha": np.zeros(2)}
    )


def _line(p, x):
    return p["a_rad"][None, :] * jnp.cos(x["theta"])[:, None]


def _lines(p, x):  # three orders and a nonlinear phase: a larger Jacobian program
    th = x["theta"][:, None] + p["phase_rad"] + x["alpha"][None, :]
    return sum(p["a_rad"][None, :] * jnp.sin(m * th) ** 2 for m in (1, 2, 3))


SMALL = Candidate("small", _line, (Param("a_rad", "rad", "channels"),))
LARGE = Candidate(
    "large",
    _lines,
    (Param("a_rad", "rad", "channels"), Param("phase_rad", "rad", linear=False)),
)


def test_a_larger_jacobian_program_weighs_more():
    """The weight is the traced Jacobian program's size, the same at every call."""
    prep = _prep()
    small, large = program_size(SMALL, prep, 16), program_size(LARGE, prep, 16)  # type: ignore[arg-type]
    assert large > small > 0
    assert program_size(LARGE, prep, 16) == large  # type: ignore[arg-type]


def test_one_process_is_every_candidates_home():
    assert homes(_prep(), 16, [SMALL, LARGE]) == {"small": 0, "large": 0}  # type: ignore[arg-type]
