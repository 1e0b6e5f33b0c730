"""The plausibility ratio's limit (``_evidence.ratio_limit``): a candidate's own size against
what it explains, read on part of a turn at the conditioning limit (session 39)."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from encdesign.diagnose import diagnose
from encdesign.diagnose.engine._evidence import ratio_limit
from encdesign.diagnose.engine._settings import DEFAULT_SETTINGS


def test_the_ratio_limit_is_the_conditioning_limit_on_part_of_a_turn_only():
    s = DEFAULT_SETTINGS
    whole = SimpleNamespace(settings=s, part_turn_span=None)
    part = SimpleNamespace(settings=s, part_turn_span=2.7)
    assert ratio_limit(whole) == s.plausible_ratio  # type: ignore[arg-type]
    lim = ratio_limit(part)  # type: ignore[arg-type]
    assert lim == max(s.plausible_ratio, 1.0 / math.sqrt(1.0 - s.collinear_refuse**2))
    assert 9.9 < lim < 10.1  # collinear_refuse 0.995


def test_a_shift_on_part_of_a_turn_is_named_though_the_base_takes_most_of_it():
    """Training ``short_arcs.py --set effects --seed 6756`` record 1 (session 38's fresh
    miss): an ``eccentricity_shift`` of 12x the noise at 1.815 s (3 heads, 1500 rows, one
    run over 0.58 turn, disk orders 1-12). Seen once, the base's disk orders take 96 % of the
    shift's energy: its own size 5.29 noise units is 5.1x what it explains, and main
    (a25ef9d) refused it by ``plausible_ratio`` (4) and left the record ``unexplained``.
    Read at the conditioning limit (10) it is named, its time and size those drawn."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from short_arcs import short_record

    rec, _ = short_record(np.random.default_rng([6756, 44, 1]), "eccentricity_shift")
    d = diagnose(rec).doc
    assert [e["name"] for e in d["effects"]] == ["eccentricity_shift"], d["report"]
    p = d["effects"][0]["params"]
    assert abs(p["shift_time_s"]["value"] - 1.815) < 0.01
    size = math.hypot(p["shift_x_m"]["value"], p["shift_y_m"]["value"])
    assert abs(size - 7.9e-8) < 0.1 * 7.9e-8  # 11.96 x 2.2e-7 rad x 0.03 m


def test_a_doubted_candidate_is_not_named_over_an_undoubted_twin():
    """Training ``finder_variations.py --set high --seed 6745`` record 6 (session 38's fresh
    miss): one sensor of 16 signal periods against its reference, disk orders 1-16, 48
    turns. The base stops at order 15 (order 16 is the signal period's), and main (a25ef9d)
    named ``bearing_wobble`` at frequency ratio 15.9999, doubted as synchronous, over
    ``interpolation_error``: the same fitted error (correlation 1.000, chi-square +1.5), its
    lead in the criterion only its fewer parameters. The record cannot tell them apart, so
    the doubt decides: the undoubted twin is named (the record's limit: the disk's top order
    is the signal period's)."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from finder_variations import clean_record

    rec, _ = clean_record(np.random.default_rng([6745, 6]), 13, 21)
    d = diagnose(rec).doc
    assert [e["name"] for e in d["effects"]] == ["interpolation_error"], d["report"]
    why = [r["reason"] for r in d["rejected"] if r["name"] == "bearing_wobble"]
    assert why and "synchronous" in why[0], d["rejected"]
