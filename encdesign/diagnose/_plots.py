"""Plot pieces shared by the finders' figures."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np


def rms_steps(d: Mapping[str, Any]) -> tuple[list[str], list[float], list[float]]:
    """From a diagnose JSON contract: step names (``base``, then each named effect) and
    their fitted and held-out residual RMS (units of the recording)."""
    names = ["base"] + [e["name"] for e in d["effects"]]
    fitted = [d["rms_before"]] + [e["rms_after"] for e in d["effects"]]
    heldout = [d["heldout_rms_before"]] + [e["heldout_rms_after"] for e in d["effects"]]
    return names, fitted, heldout


def rms_bars(
    ax: Any,
    names: Sequence[str],
    fitted: Sequence[float],
    heldout: Sequence[float],
    *,
    scale: float = 1.0,
    **tick_kw: Any,
) -> None:
    """Grouped bars of fitted and held-out RMS per model step on ``ax`` (values times
    ``scale``; ``tick_kw`` goes to the x tick labels)."""
    x = np.arange(len(names))
    ax.bar(x - 0.2, np.asarray(fitted) * scale, 0.4, label="fitted")
    ax.bar(x + 0.2, np.asarray(heldout) * scale, 0.4, label="held out")
    ax.set_xticks(x, names, **tick_kw)
