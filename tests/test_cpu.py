"""The default CPU devices (``encdesign/_cpu.py``): chosen from the cores unless the user
chose, and the same values as one device (a subprocess with encdesign's default on 2
devices: this suite runs with ``OMP_NUM_THREADS=1``, i.e. one device per process)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import (
    SCALE_BUILDS,
    SCALE_DESIGN,
    SCALE_TOLERANCES,
    cramer_model,
    env_without_device_count,
)

from encdesign import EncdesignInputError
from encdesign._cpu import DEVICES_PER_CORE, ENV, choose_cpu_devices
from encdesign.physics import head_errors_batch, stack_models

ROOT = Path(__file__).resolve().parent.parent
RTOL = 1e-13


def test_device_count_follows_cores_unless_the_user_chose():
    assert choose_cpu_devices({}, 2) == max(1, round(2 * DEVICES_PER_CORE))
    assert choose_cpu_devices({}, 8) == max(1, round(8 * DEVICES_PER_CORE))
    assert choose_cpu_devices({"OMP_NUM_THREADS": "1"}, 2) == 1  # pytest -n 2, say
    assert choose_cpu_devices({ENV: "3", "OMP_NUM_THREADS": "1"}, 2) == 3
    flags = {"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}
    assert choose_cpu_devices(flags, 2) is None
    assert choose_cpu_devices({"JAX_NUM_CPU_DEVICES": "4"}, 2) is None
    for bad in ("two", "0", "-1"):
        with pytest.raises(EncdesignInputError, match=ENV):
            choose_cpu_devices({ENV: bad}, 2)
    with pytest.raises(EncdesignInputError, match="OMP_NUM_THREADS"):
        choose_cpu_devices({"OMP_NUM_THREADS": "x"}, 2)


def test_bad_device_argument_is_refused():
    batch = stack_models([cramer_model(), cramer_model()])
    with pytest.raises(ValueError, match="devices"):
        head_errors_batch(batch, jnp.zeros(3), devices=0)
    with pytest.raises(ValueError, match="local devices"):
        head_errors_batch(batch, jnp.zeros(3), devices=len(jax.local_devices()) + 1)


def _population():
    ecc = [1e-6, -2e-6, 3e-6, 4e-6, -5e-6]  # 5 designs: not a multiple of 2, the last slice padded
    return stack_models(
        [
            cramer_model(eccentricity_m=(e, 0.5 * e), runout_amplitude_m=1e-6, runout_ratio=0.4)
            for e in ecc
        ]
    )


THETA = np.arange(96) * (2 * np.pi / 96)


def _loss(batch, scale):
    """Mean squared head error with the eccentricities scaled by ``scale`` (rad^2)."""
    b = eqx.tree_at(lambda m: m.disk.eccentricity_m, batch, batch.disk.eccentricity_m * scale)
    return jnp.mean(head_errors_batch(b, THETA, THETA / (2 * np.pi), chunk=2) ** 2)


def _mc_values():
    from encdesign.design import monte_carlo
    from encdesign.objectives import EncoderDesign, Tolerances, n_build_normals, residual_rms

    d = EncoderDesign(**SCALE_DESIGN)
    tv = Tolerances(**SCALE_TOLERANCES).vector()
    fn = lambda t, z: residual_rms(d, Tolerances.from_vector(t), z)
    res = monte_carlo(
        fn, tv, key=jax.random.key(3), n=SCALE_BUILDS, dim=n_build_normals(d), chunk_size=64
    )
    return res.values


def _child_results() -> dict:
    """Run in the subprocess: encdesign's default devices (2)."""
    batch = _population()
    t = THETA / (2 * np.pi)
    g = jax.grad(_loss, argnums=1)(batch, 1.0)
    h = 1e-4
    fd = (_loss(batch, 1.0 + h) - _loss(batch, 1.0 - h)) / (2 * h)
    return {
        "devices": jax.device_count(),
        "split": np.asarray(head_errors_batch(batch, THETA, t, chunk=2)).tolist(),
        "one": np.asarray(head_errors_batch(batch, THETA, t, chunk=2, devices=1)).tolist(),
        "grad": float(g),
        "fd": float(fd),
        "mc": _mc_values().tolist(),
    }


def test_default_devices_give_the_values_of_one_device(tmp_path):
    env = env_without_device_count()
    env.pop("OMP_NUM_THREADS", None)
    env[ENV] = "2"  # what the default gives on 2 cores, on any machine
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(ROOT / "tests"), env.get("PYTHONPATH", "")])
    out = tmp_path / "child.json"
    code = (
        "import json, sys, test_cpu; "
        f"open({str(out)!r}, 'w').write(json.dumps(test_cpu._child_results()))"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600
    )
    assert run.returncode == 0, run.stderr[-4000:]
    child = json.loads(out.read_text())
    assert child["devices"] == 2
    here = np.asarray(head_errors_batch(_population(), THETA, THETA / (2 * np.pi), chunk=2))
    scale = np.max(np.abs(here))
    for name in ("split", "one"):
        np.testing.assert_allclose(np.asarray(child[name]), here, rtol=0, atol=RTOL * scale)
    mc = _mc_values()
    np.testing.assert_allclose(np.asarray(child["mc"]), mc, rtol=RTOL)
    # the split path's gradient: the same as here and as finite differences
    g_here = float(jax.grad(_loss, argnums=1)(_population(), 1.0))
    assert child["grad"] == pytest.approx(g_here, rel=RTOL)
    assert child["grad"] == pytest.approx(child["fd"], rel=1e-6)
