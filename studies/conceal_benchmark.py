"""Conceal benchmark: the discrepancy finder run blind on recordings with hidden effects.

Simulated benches (``encdesign._conceal``: 3+1 and 2+1 multihead encoders, three runs at
different speeds, read noise, ``temp_c``, with and without ``theta_ref``), each carrying one
catalog effect hidden near the noise, masked by larger base errors at the same order,
aliased by coarse sampling or present in only part of the record; plus clean recordings
and out-of-catalog effects (``count_jump``, ``chirp``). ``encdesign.diagnose`` never sees
the truth. Scored: % of hidden effects named correctly, % of clean recordings with no claim,
out-of-catalog effects reported as ``unexplained`` at the right place, held-out RMS
improvement whenever an effect is named; a confusion table truth x verdict/name.

Outputs (``--out``): ``conceal-benchmark.json``, ``confusion.png``, ``heldout.png`` and the
recordings under ``recordings/``.
"""

from __future__ import annotations

import sys
import time

import jax
import numpy as np

from encdesign._conceal import write_concealed
from encdesign._diagnose import diagnose
from encdesign._effects import CATALOG_MULTIHEAD
from encdesign._study import new_figure, save_figure, study_parser, write_results

NAME = "conceal-benchmark"

PLAN = {
    "beam_tilt_axial": [
        ("near_noise", "3+1", True),
        ("masked", "3+1", True),
        ("near_noise", "2+1", True),
        ("masked", "3+1", False),
        ("near_noise", "2+1", False),
    ],
    "bearing_wobble": [
        ("near_noise", "3+1", True),
        ("near_noise", "2+1", True),
        ("near_noise", "3+1", False),
        ("near_noise", "3+1", True),
        ("near_noise", "2+1", False),
    ],
    "vibration": [
        ("near_noise", "3+1", True),
        ("aliased", "3+1", True),
        ("partial", "3+1", True),
        ("aliased", "2+1", False),
        ("partial", "2+1", True),
    ],
    "thermal_drift": [
        ("near_noise", "3+1", True),
        ("near_noise", "2+1", True),
        ("masked", "3+1", True),
        ("near_noise", "3+1", False),
        ("near_noise", "2+1", False),
    ],
    "interpolation_error": [
        ("aliased", "3+1", True),
        ("aliased", "2+1", True),
        ("aliased", "3+1", False),
        ("aliased", "3+1", True),
        ("aliased", "2+1", False),
    ],
    "eccentricity_shift": [
        ("partial", "3+1", True),
        ("partial", "2+1", True),
        ("partial", "3+1", False),
        ("partial", "3+1", True),
        ("partial", "2+1", False),
    ],
    None: [
        ("near_noise", "3+1", True),
        ("near_noise", "2+1", True),
        ("near_noise", "3+1", False),
        ("near_noise", "2+1", False),
        ("near_noise", "3+1", True),
        ("near_noise", "2+1", True),
        ("near_noise", "3+1", True),
        ("near_noise", "3+1", False),
    ],
    "count_jump": [
        ("near_noise", "3+1", True),
        ("near_noise", "2+1", True),
        ("near_noise", "3+1", False),
    ],
    "chirp": [
        ("near_noise", "3+1", True),
        ("near_noise", "2+1", True),
        ("near_noise", "3+1", False),
    ],
}
QUICK = {
    None: [("near_noise", "3+1", True)],
    "vibration": [("near_noise", "3+1", True)],
    "count_jump": [("near_noise", "3+1", True)],
}


def _located(truth: dict, unexplained: list[dict]) -> bool:
    w = truth.get("where", {})
    for u in unexplained:
        uw = u["where"]
        if not set(w.get("heads", [])) & set(uw["heads"]):
            continue
        if truth["effect"] == "count_jump":
            if (
                any(abs(t - w["times_s"][0]) < 0.5 for t in uw["times_s"])
                and w["runs"][0] in uw["runs"]
            ):
                return True
        elif truth["effect"] == "chirp":
            lo, hi = w["frequencies_hz"]
            if any(lo - 2 <= f <= hi + 2 for f in uw["frequencies_hz"]):
                return True
    return False


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; returns 0."""
    args = study_parser(NAME, __doc__).parse_args(argv)
    plan = QUICK if args.quick else PLAN
    spr = 600 if args.quick else 2000
    rows = []
    t_all = time.perf_counter()
    i = 0
    total = sum(len(v) for v in plan.values())
    for effect, cases in plan.items():
        for conc, layout, ref in cases:
            seed = args.seed * 1000 + i
            path = args.out / "recordings" / f"rec{i:03d}.toml"
            rec, truth = write_concealed(
                path,
                key=jax.random.key(seed),
                effect=effect,
                concealment=conc,
                layout=layout,
                theta_ref=ref,
                samples_per_run=spr,
            )
            t0 = time.perf_counter()
            d = diagnose(rec)
            dt = time.perf_counter() - t0
            named = d.effects[0].name if d.effects else None
            label = named or d.verdict
            row = dict(
                recording=str(path),
                seed=seed,
                truth=effect or "clean",
                concealment=conc,
                layout=layout,
                theta_ref=ref,
                verdict=d.verdict,
                named=[e.name for e in d.effects],
                label=label,
                heldout_rms_before=d.heldout_rms_before,
                heldout_rms_after=d.heldout_rms_final,
                heldout_improvement=1 - d.heldout_rms_final / d.heldout_rms_before,
                time_s=dt,
            )
            if effect in CATALOG_MULTIHEAD:
                row["correct"] = named == effect
            elif effect is None:
                row["correct"] = d.verdict == "consistent"
            else:
                row["correct"] = d.verdict == "unexplained" and _located(truth, d.unexplained)
            rows.append(row)
            i += 1
            print(
                f"[{NAME}] {i}/{total} {row['truth']:20s} {conc:10s} {layout} "
                f"ref={int(ref)} -> {label:20s} {'ok' if row['correct'] else 'WRONG'} "
                f"({dt:.1f} s)",
                file=sys.stderr,
                flush=True,
            )
    cat = [r for r in rows if r["truth"] in CATALOG_MULTIHEAD]
    clean = [r for r in rows if r["truth"] == "clean"]
    ooc = [r for r in rows if r["truth"] not in CATALOG_MULTIHEAD and r["truth"] != "clean"]
    named_rows = [r for r in rows if r["named"]]
    truths = list(dict.fromkeys(r["truth"] for r in rows))
    labels = sorted({r["label"] for r in rows})
    confusion = {
        t: {lab: sum(1 for r in rows if r["truth"] == t and r["label"] == lab) for lab in labels}
        for t in truths
    }
    summary = dict(
        n_recordings=len(rows),
        named_correctly_pct=100 * np.mean([r["correct"] for r in cat]) if cat else None,
        clean_no_claim_pct=100 * np.mean([r["correct"] for r in clean]) if clean else None,
        clean_false_positive_pct=100 - 100 * np.mean([r["correct"] for r in clean])
        if clean
        else None,
        out_of_catalog_located_pct=100 * np.mean([r["correct"] for r in ooc]) if ooc else None,
        heldout_improved_whenever_named=bool(
            all(r["heldout_rms_after"] < r["heldout_rms_before"] for r in named_rows)
        ),
        median_heldout_improvement_pct=100
        * float(np.median([r["heldout_improvement"] for r in named_rows]))
        if named_rows
        else None,
        per_effect_correct_pct={
            t: 100 * np.mean([r["correct"] for r in rows if r["truth"] == t]) for t in truths
        },
        confusion=confusion,
        median_time_s=float(np.median([r["time_s"] for r in rows])),
        total_time_s=time.perf_counter() - t_all,
        rows=rows,
    )
    figs = []
    if not args.no_plots:
        fig, ax = new_figure(figsize=(7.5, 4.5))
        mat = np.array([[confusion[t][lab] for lab in labels] for t in truths])
        ax.imshow(mat, cmap="Blues")
        ax.set_xticks(range(len(labels)), labels, rotation=40, ha="right", fontsize=7)
        ax.set_yticks(range(len(truths)), truths, fontsize=7)
        for a in range(len(truths)):
            for b in range(len(labels)):
                if mat[a, b]:
                    ax.text(b, a, str(mat[a, b]), ha="center", va="center", fontsize=8)
        ax.set_xlabel("finder's verdict / first named effect")
        ax.set_ylabel("hidden truth")
        ax.set_title("conceal benchmark: confusion table")
        figs.append(save_figure(fig, args.out, "confusion.png"))
        fig, ax = new_figure(figsize=(6, 3.5))
        for r in rows:
            c = "tab:green" if r["correct"] else "tab:red"
            ax.scatter(r["heldout_rms_before"] * 1e6, r["heldout_rms_after"] * 1e6, c=c, s=14)
        lim = max(r["heldout_rms_before"] for r in rows) * 1e6 * 1.05
        ax.plot([0, lim], [0, lim], "k:", lw=0.8)
        ax.set_xlabel("held-out RMS, base model (urad)")
        ax.set_ylabel("held-out RMS, final model (urad)")
        ax.set_title("held-out residual (green: correct verdict)")
        figs.append(save_figure(fig, args.out, "heldout.png"))
    write_results(args, NAME, summary, figs)
    print(
        f"named correctly {summary['named_correctly_pct']}%, clean without claim "
        f"{summary['clean_no_claim_pct']}%, out-of-catalog located "
        f"{summary['out_of_catalog_located_pct']}%"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
