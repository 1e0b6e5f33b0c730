"""One sensor against its reference: ``interpolation_error`` beside the sensor's own error.

On one sensor the signal phase is ``L`` times the shaft angle, so the harmonic ``h`` of
``interpolation_error`` is a static error at shaft order ``h L``: the sensor's own error
function (the base model's orders) at that order as much. Where the sensor's own error runs
past ``h L`` (the base's orders or located integer orders above it), the record cannot tell
the two apart: a named ``interpolation_error`` reports the base's order as confounded (an
identifiability conflict, not a finding of either)."""

from __future__ import annotations

import re

import numpy as np

from ...engine._protocol import Prepared
from ._vibration_doubt import order_res


def own_order_confound(prep: Prepared, doc: dict) -> dict:
    """Add to a named ``interpolation_error`` of a one-sensor record the ``confounded_with``
    entry ``base_order_<h L>`` for each fitted harmonic whose shaft order lies inside the
    orders of the sensor's own error (some below it, some above it); returns ``doc``."""
    L = int(getattr(prep.ctx, "signal_periods", 0) or 0)
    if prep.n_channels != 1 or not prep.ctx.has_ref or not L:
        return doc
    own = set(range(1, int(doc.get("base", {}).get("max_order") or 0) + 1))
    for u in doc.get("unexplained", []):
        if u.get("view") == "orders":
            own |= {round(o) for o in u["where"]["orders"]}
    for e in doc.get("effects", []):
        coef = (e.get("params") or {}).get("coef")
        if e["name"] != "interpolation_error" or not coef:
            continue
        v = np.asarray(coef["value"], float).reshape(2, 2, -1)  # harmonics 1, 2 x cos / sin
        for i, h in enumerate((1, 2)):  # the orders L and 2 L it fits
            m = h * L
            if not np.any(v[i]) or not (any(k < m for k in own) and any(k > m for k in own)):
                continue
            e["confounded_with"] = [
                *(e.get("confounded_with") or []),
                {
                    "name": f"base_order_{m}",
                    "reason": f"on one sensor its harmonic {h} of the {L} signal periods is a "
                    f"static error at shaft order {m}, and the sensor's own error function "
                    f"(the base model's orders, or orders located beside it) runs past that "
                    "order: the record cannot tell the sensor's own error there from an "
                    "interpolation error",
                    "rule": "identifiable",
                    "delta_bic": None,
                    "params": {"order": m},
                    "separate_by": "a sensor with another number of signal periods on the same "
                    "disk, or a second head at another azimuth",
                },
            ]
    return doc


STAIRCASE_SEPARATE_BY = (
    "a reading of finer resolution (another LSB) or a sensor with another number of signal "
    "periods: the staircase's orders follow the LSB, the interpolation error's the signal "
    "periods"
)


def _coincident(prep: Prepared, doc: dict) -> tuple[dict | None, float, list[int]]:
    """``(quantization's effect, counts per turn, [h L ...])``: the named ``quantization``
    and the orders ``h L`` (``h`` = 1, 2) of ``interpolation_error`` that are one of the
    staircase's orders ``k 2 pi / q`` (within the record's resolution in orders,
    ``1 / turns``, at least ``integer_order_tol``: the LSB of a reading scaled to radians
    need not be a whole number of counts per turn); ``(None, 0, [])``
    where none is or nothing is named."""
    L = int(getattr(prep.ctx, "signal_periods", 0) or 0)
    quant = next((e for e in doc.get("effects", []) if e["name"] == "quantization"), None)
    if prep.n_channels != 1 or not prep.ctx.has_ref or not L or quant is None:
        return None, 0.0, []
    q = float(np.ravel(np.asarray(quant["params"]["lsb_rad"]["value"], float))[0])
    n = 2 * np.pi / q
    tol = order_res(prep.ctx)
    at = [
        h * L for h in (1, 2) if round(h * L / n) >= 1 and abs(h * L - round(h * L / n) * n) <= tol
    ]
    return (quant if at else None), n, at


def _pair(doc: dict, named: dict, other: str, entry: dict) -> None:
    named["confounded_with"] = [*(named.get("confounded_with") or []), entry]
    doc.setdefault("confounded", []).append(
        {
            "pair": [named["name"], other],
            "correlation": entry["correlation"],
            "delta_bic": None,
            "separate_by": entry["separate_by"],
            "reason": entry["reason"] + f"; {named['name']} is named",
            "rule": entry["rule"],
        }
    )


def staircase_confound(prep: Prepared, doc: dict) -> dict:
    """One quantized sensor whose staircase (lines at shaft orders ``k 2 pi / q``) has
    ``interpolation_error``'s order ``L`` or ``2 L`` among its orders: the record cannot tell
    the two apart there. An error ahead of the quantizer that repeats every LSB (period
    ``q`` in the reading) only moves where the steps fall, by the same amount in every step:
    the lattice's offset, which the data fix; added after it, it is a line at the
    staircase's own order. The report says so, as for other pairs the record cannot
    separate (issue 44, session 22; it said nothing before):

    * ``interpolation_error`` named: its ``confounded_with`` gets ``quantization`` (rule
      ``identifiable``, correlation 1: at that order the two are one function), and a
      ``confounded`` pair;
    * refused because the quantization staircase takes its gain (``Candidate.rivals``,
      rule ``located_share_min``; a staircase beyond what its LSB makes is no rival,
      :func:`~encdesign.diagnose.kinds.multihead._reference_terms._staircase_plausible`):
      the refusal becomes ``quantization``'s ``confounded_with`` entry and a pair
      (correlation ``sqrt(1 - kept)``: the staircase takes ``1 - kept`` of its gain, a
      squared correlation). Returns ``doc``."""
    from ._reference_terms import STAIRCASE_RIVAL

    quant, n, at = _coincident(prep, doc)
    if quant is None:
        return doc
    L = int(prep.ctx.signal_periods)
    same = (
        f"at shaft order {at[0]} the quantization staircase ({n:.6g} counts per turn) and "
        f"interpolation_error ({L} signal periods) are one static error: ahead of the "
        "quantizer an error repeating every LSB only moves the steps (the lattice's offset)"
    )
    interp = next((e for e in doc["effects"] if e["name"] == "interpolation_error"), None)
    if interp is not None:
        _pair(
            doc,
            interp,
            "quantization",
            {
                "name": "quantization",
                "reason": same,
                "rule": "identifiable",
                "delta_bic": None,
                "params": {"orders": at},
                "correlation": 1.0,
                "separate_by": STAIRCASE_SEPARATE_BY,
            },
        )
        return doc
    refused = [
        r
        for r in doc.get("rejected", [])
        if r["name"] == "interpolation_error"
        and r.get("rule") == "located_share_min"
        and STAIRCASE_RIVAL in r.get("reason", "")
    ]
    if not refused:
        return doc
    m = re.search(r"keeps only (\d+)%", refused[-1]["reason"])
    kept = float(m.group(1)) / 100 if m else 0.0
    _pair(
        doc,
        quant,
        "interpolation_error",
        {
            "name": "interpolation_error",
            "reason": f"{same}: {refused[-1]['reason']}",
            "rule": "located_share_min",
            "delta_bic": None,
            "params": {"orders": at},
            "correlation": float(np.sqrt(max(1.0 - kept, 0.0))),
            "separate_by": STAIRCASE_SEPARATE_BY,
        },
    )
    doc["rejected"] = [x for x in doc["rejected"] if x not in refused]
    return doc
