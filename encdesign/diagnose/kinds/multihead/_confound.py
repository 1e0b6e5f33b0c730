"""One sensor against its reference: ``interpolation_error`` beside the sensor's own error.

On one sensor the signal phase is ``L`` times the shaft angle, so the harmonic ``h`` of
``interpolation_error`` is a static error at shaft order ``h L``: the sensor's own error
function (the base model's orders) at that order as much. Where the sensor's own error runs
past ``h L`` (the base's orders or located integer orders above it), the record cannot tell
the two apart: a named ``interpolation_error`` reports the base's order as confounded (an
identifiability conflict, not a finding of either)."""

from __future__ import annotations

import numpy as np

from ...engine._protocol import Prepared


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
