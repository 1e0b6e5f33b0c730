"""A new recording kind is one module and one registry line (issue 40, acceptance).

The toy kind below is written, as a newcomer would write it, into a module of its own (here
a file in a temporary folder, imported like any module); registering it is one line,
``KINDS["toy"] = TOY`` (``monkeypatch.setitem`` undoes it after the test). Nothing else in
the package changes: ``diagnose()`` looks the kind up and runs it through the same engine
entry as every other kind.
"""

from __future__ import annotations

import importlib.util
import sys
import textwrap

import numpy as np
import pytest

from encdesign.diagnose import diagnose
from encdesign.diagnose._registry import KINDS
from encdesign.diagnose.engine._kind import AbstractKind
from encdesign.io import Recording

TOY_MODULE = '''
"""A toy kind: one sensor read against a reference angle; base model the sensor's error
function of the angle (orders 1..M) and one constant; one candidate, a drift in time."""

from typing import ClassVar, final

import jax.numpy as jnp
import numpy as np

from encdesign.diagnose import Candidate, Param
from encdesign.diagnose.engine._kind import AbstractKind
from encdesign.diagnose.engine._prepare import prepare
from encdesign.diagnose.engine._protocol import KindData


def _base(M):
    m = jnp.arange(1, M + 1, dtype=float)

    def fn(p, x):
        arg = x["theta"][:, None] * m[None, :]
        e = jnp.cos(arg) @ p["cos_rad"] + jnp.sin(arg) @ p["sin_rad"]
        return (e + x["run_onehot"] @ p["offset_rad"])[:, None]

    return Candidate(
        "base",
        fn,
        (
            Param("offset_rad", "rad", "runs"),
            Param("cos_rad", "rad", (M,)),
            Param("sin_rad", "rad", (M,)),
        ),
        kinds=("toy",),
        explanation="base model: the sensor's error function of the angle",
    )


DRIFT = Candidate(
    "toy_drift",
    lambda p, x: (p["slope_rad_s"] * x["tau"])[:, None],
    (Param("slope_rad_s", "rad/s"),),
    signature=("time", "drift"),
    kinds=("toy",),
    explanation="the sensor's zero drifts in time",
)


@final
class ToyKind(AbstractKind):
    name: ClassVar[str] = "toy"
    default_max_order: ClassVar[int] = 4
    noise_replaces: ClassVar[bool] = False
    grows_orders: ClassVar[bool] = False
    reading_lattice: ClassVar[bool] = False

    def data(self, rec, settings=None):
        ref = np.asarray(rec.columns["theta_ref"], float)
        reading = np.asarray(rec.columns["s0"], float)
        return KindData(
            y=(reading - ref)[:, None],
            shaft=ref,
            t=np.asarray(rec.columns["t"], float),
            run=np.asarray(rec.runs),
            reading=reading[:, None],
            theta_ref=ref,
            temp=None,
            alpha=np.zeros(1),
            radius_m=None,
            signal_periods=0,
            project=False,
            unit="rad",
            channel_names=["s0"],
            sensor="toy",
            where="toy recording",
        )

    def views(self, prep):
        return ("orders", "time", "drift")

    def prepare(self, kd, meta, settings):
        return prepare(kd, meta, settings)

    def base(self, prep, max_order):
        return [(_base(max_order), {})], {"unidentifiable": []}

    def candidates(self, ctx):
        return (DRIFT,)

    def max_order_limit(self, prep):
        return 8

    def noise(self, prep, base_resid):
        return None

    def refine(self, terms, prep):
        return None

    def align(self, terms, prep):
        return None

    def summary(self, prep, base_params):
        return {}

    def finish(self, prep, doc, settings):
        return doc

    def report_lines(self, doc):
        return ""

    def plots(self, d, folder):
        return []


TOY = ToyKind()
'''


@pytest.fixture
def toy_kind(tmp_path, monkeypatch):
    """The toy kind's module, written and imported, and its one registry line."""
    path = tmp_path / "toy_kind.py"
    path.write_text(textwrap.dedent(TOY_MODULE), encoding="utf-8")
    spec = importlib.util.spec_from_file_location("toy_kind", path)
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "toy_kind", mod)
    spec.loader.exec_module(mod)
    monkeypatch.setitem(KINDS, "toy", mod.TOY)  # the registry line
    return mod.TOY


def toy_record(seed: int, drift_rad_s: float) -> Recording:
    """20 turns at 1 rev/s, 200 samples/s: the sensor's error (orders 1 and 2), white noise
    of 1 urad and a drift of its zero."""
    rng = np.random.default_rng(seed)
    t = np.arange(4000) / 200.0
    ref = 2 * np.pi * t + 0.3
    err = 4e-5 * np.cos(ref + 0.2) + 1.5e-5 * np.sin(2 * ref) + drift_rad_s * t
    s0 = ref + err + 1e-6 * rng.standard_normal(t.size)
    return Recording(kind="toy", meta={}, columns={"t": t, "theta_ref": ref, "s0": s0})


def test_the_registry_holds_every_kind_of_the_package():
    assert set(KINDS) == {"multihead", "motion", "sds", "quadrature"}
    assert all(isinstance(k, AbstractKind) and k.name == name for name, k in KINDS.items())


@pytest.mark.parametrize("seed", [3, 11])
def test_a_toy_kind_is_one_module_and_one_registry_line(toy_kind, seed):
    clean = diagnose(toy_record(seed, 0.0))
    assert clean.verdict == "consistent", clean.doc["report"]
    drift = diagnose(toy_record(seed, 2e-6))  # 40 urad over the record: 40x the noise
    assert drift.verdict == "missing_physics", drift.doc["report"]
    assert [e.name for e in drift.effects] == ["toy_drift"]
    assert drift.doc["effects"][0]["params"]["slope_rad_s"]["value"] == pytest.approx(
        2e-6, rel=0.05
    )


def test_an_unregistered_kind_is_refused_by_name():
    with pytest.raises(ValueError, match="no finder for recording kind 'toy'"):
        diagnose(toy_record(0, 0.0))
