"""``interpolation_error`` against the quantization staircase on one sensor (issue 44,
s21-quant44): a sensor read on a value lattice of step ``q`` carries a staircase at shaft
orders ``k 2 pi / q``; where ``L`` or ``2 L`` (``L`` signal periods per turn) is one of
them, the harmonic pair fitted the staircase's fundamental with a free size and phase, was
named, and ``quantization`` was refused (amplitude 1.42, training record 7558 of
``test_vibration_doubt``). The staircase is now ``interpolation_error``'s rival
(``Candidate.rivals``, rule ``located_share_min``).

Generated records (the concealed benchmark's sensor plan): the same record with ``L`` set
to the lattice's counts per turn or to half of it (no signal error), and controls where a
real ``interpolation_error`` sits beside the quantization at the plan's own ``L``. Seeds
7580-7589 are this work's training seeds (``benchmarks/SEEDS.md``)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import sweep

from encdesign import Recording
from encdesign.diagnose import diagnose
from encdesign.simulate import draw_plan, fix_plan, simulate_plan


def _coincides(periods: int, counts: int) -> bool:
    """Whether ``L`` or ``2 L`` is a whole number of the staircase's counts per turn."""
    return any(h * periods % counts == 0 for h in (1, 2))


def _record(seed: int, case: str) -> tuple[Recording, dict]:
    """``case``: ``"L"`` or ``"2L"``: quantization and a reading delay, ``L`` set so that
    ``L`` (or ``2 L``) is the lattice's counts per turn ``2 pi / q``; ``"real"``:
    quantization and an interpolation error at the plan's own ``L`` (16, 21 or 2048),
    moved to 21 where the staircase's orders hold ``L`` or ``2 L``."""
    rng = np.random.default_rng([seed, 44, 1])
    plan = draw_plan(rng, "sensor", "compound")
    effects = ["quantization", "interpolation_error" if case == "real" else "reading_delay"]
    plan = fix_plan(dict(plan, effects=effects, amplitude=1.0), rng)
    state = rng.bit_generator.state
    _, truth = simulate_plan(rng, plan)
    n = int(round(2 * np.pi / truth["lsb_rad"]))
    rng.bit_generator.state = state
    if case == "real":
        if _coincides(plan["periods"], n):
            plan = dict(plan, periods=21)
    else:
        plan = dict(plan, periods=n if case == "L" else n // 2)
    rec, truth = simulate_plan(rng, plan)
    truth["counts_per_turn"] = n
    return rec, truth


CASES = [(s, c) for s in range(7580, 7587) for c in ("L", "2L")]
CASES += [(s, "real") for s in range(7587, 7590)]


# ``make test`` runs one record of each case; the others are the ``sweep`` tier
# (``make test-sweeps``; session 31, CI time)
KEEP = ((7580, "L"), (7580, "2L"), (7587, "real"))


@pytest.mark.parametrize(("seed", "case"), sweep(CASES, KEEP))
def test_the_staircase_is_no_interpolation_error(seed, case):
    rec, truth = _record(seed, case)
    d = diagnose(rec).doc
    named = sorted(e["name"] for e in d["effects"])
    why = (truth["plan"], truth.get("counts_per_turn"), named, d["rejected"])
    assert "quantization" in named, why
    if case == "real":
        assert "interpolation_error" in named, why
    else:
        assert "interpolation_error" not in named, why


def test_the_training_record_7558_names_quantization_not_interpolation_error():
    """``test_vibration_doubt``'s record 7558 (a resolver of ``L`` = 2048 read at 4096
    counts per turn): main named ``interpolation_error`` and ``vibration`` beside the truth."""
    from test_vibration_doubt import _quantized_sensor

    rec, truth = _quantized_sensor(7558)
    d = diagnose(rec).doc
    named = sorted(e["name"] for e in d["effects"])
    assert named == ["quantization", "reading_delay"], (truth["plan"], named, d["rejected"])
