"""Plot pieces shared by the finders' figures."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import os

    from matplotlib.axes import Axes


def rms_steps(d: Mapping[str, Any]) -> tuple[list[str], list[float], list[float]]:
    """From a diagnose JSON contract: step names (``base``, then each named effect) and
    their fitted and held-out residual RMS (units of the recording)."""
    names = ["base"] + [e["name"] for e in d["effects"]]
    fitted = [d["rms_before"]] + [e["rms_after"] for e in d["effects"]]
    heldout = [d["heldout_rms_before"]] + [e["heldout_rms_after"] for e in d["effects"]]
    return names, fitted, heldout


def rms_bars(
    ax: Axes,
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


def engine_plots(d: Any, out_dir: str | os.PathLike) -> list:
    """PNG figures of an engine diagnosis: RMS steps (fitted and held out), the residual
    against time before and after (excluded segments shaded), and the residual spectra."""
    from pathlib import Path

    from ...io._study import new_figure, save_figure

    out = Path(out_dir)
    pd = d.plot_data
    prep, r0, r1 = pd["prep"], pd["base_resid"], pd["final_resid"]
    doc = d.doc
    paths = []
    fig, ax = new_figure(figsize=(6, 3.5))
    rms_bars(ax, *rms_steps(doc), fontsize=8)
    ax.axhline(float(np.mean(doc["noise"]["per_channel"])), color="k", ls=":", label="noise")
    ax.set_ylabel(f"residual RMS ({doc['unit']})")
    ax.set_title(f"verdict: {doc['verdict']}")
    ax.legend(loc="best", fontsize=8)
    paths.append(save_figure(fig, out, "rms_before_after.png"))
    C = r0.shape[1]
    fig, axes = new_figure(C, 1, figsize=(7, 1.6 * C + 1.0), sharex=True)
    axes = np.atleast_1d(axes)
    tau = prep.rows["tau"]
    starts = annotate_run_starts(axes[0], tau, prep.rows["t"], np.asarray(prep.run_ids)[prep.run])
    for k in range(C):
        ax = axes[k]
        for i in starts[1:]:
            ax.axvline(float(tau[i]), color="0.3", lw=0.5)
        ax.plot(tau, r0[:, k], ",", color="tab:red", label="base")
        ax.plot(tau[prep.keep], r1[prep.keep, k], ",", color="tab:blue", label="final")
        bad = ~prep.keep
        if bad.any():
            lo, hi = np.nanmin(r0[:, k]), np.nanmax(r0[:, k])
            ax.fill_between(tau, lo, hi, where=bad, color="0.85", step="mid", label="excluded")
        ax.set_ylabel(prep.kd.channel_names[k], fontsize=8)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel(
        "time, runs end to end, pauses removed (s); each run's start on the recording's t above"
    )
    paths.append(save_figure(fig, out, "residuals.png"))
    fig, ax = new_figure(figsize=(7, 3.5))
    for res, lab in ((r0, "base"), (r1, "final")):
        x = np.where(prep.keep[:, None], res, 0.0)
        X = np.abs(np.fft.rfft(x - x.mean(0), axis=0)).mean(1) * 2 / max(prep.keep.sum(), 1)
        dt = float(np.median(np.diff(prep.rows["t"])))
        f = np.fft.rfftfreq(x.shape[0], dt)
        ax.semilogy(f[1:], X[1:] + 1e-30, lw=0.6, label=lab)
    ax.set(xlabel="frequency (Hz, runs end to end)", ylabel=f"amplitude ({doc['unit']})")
    ax.legend(loc="best", fontsize=8)
    paths.append(save_figure(fig, out, "residual_spectra.png"))
    return paths


def annotate_run_starts(ax: Any, tau: Any, t: Any, runs: Any) -> np.ndarray:
    """Each run's start written on ``ax`` with its own ``t`` (s), at its place on the
    end-to-end axis ``tau`` (s); ``runs``: the run of each row. Not above 12 runs. Returns
    the rows where the runs start."""
    runs = np.asarray(runs)
    starts = np.flatnonzero(np.r_[True, runs[1:] != runs[:-1]])
    for i in starts if starts.size <= 12 else starts[:0]:
        ax.annotate(
            f"run {runs[i]}: t = {float(t[i]):.6g} s",
            (float(tau[i]), 1.0),
            xycoords=("data", "axes fraction"),
            fontsize=6,
            va="bottom",
        )
    return starts
