"""Real recordings: the discrepancy finder on every shipped measured recording.

Runs ``encdesign diagnose`` on the nine third-party recordings in ``data/real``: the X and
Y homodyne interferometers of a nanopositioning machine (Lissajous captures, kind
``quadrature``), a raw two-channel optical encoder capture in time order (``quadrature``),
a brushless motor at 0.1 rev/s without and with anti-cogging, twice each (``motion``; the
``_1`` records begin with a return-to-zero move), and two sensors recorded against a
reference angle (a 14-bit magnetic encoder swept up and down, moteus; a MagAlpha sensor
over one turn; one-head ``multihead`` with ``theta_ref``). For each: verdict, named
effects with parameters, held-out RMS before and after, excluded segments, what stays
unexplained. Comparisons: the interferometer residual after encdesign's model against a
plain Heydemann ellipse correction; the motor orders its pole pairs and slots predict
against the orders measured, and the uncompensated record against the compensated one;
each ``_1`` motor record against its ``_0`` twin (the same names, the start move excluded
and reported); the sensors' dominant orders, direction offset and quantization (LSB and
bits of sensor and reference).

Outputs ``real-recordings.json``, the diagnosis plots of each recording in ``<recording>/``, and
``real-recordings-summary.png``. ``--quick``: the NMM X capture and one motor record.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from encdesign import load_recording
from encdesign.diagnose import candidate_orders, diagnose
from encdesign.io import new_figure, save_figure, study_parser, write_results

NAME = "real-recordings"
DATA = Path(__file__).resolve().parent.parent / "data" / "real"
RECORDINGS = [
    "nmm_x",
    "nmm_y",
    "servo_optical",
    "odrive_nocomp",
    "odrive_comp",
    "odrive_nocomp_1",
    "odrive_comp_1",
    "moteus_cal",
    "magalpha_cal",
]
QUICK = ["nmm_x", "odrive_nocomp"]
TWINS = (("odrive_nocomp", "odrive_nocomp_1"), ("odrive_comp", "odrive_comp_1"))
SENSORS = ("moteus_cal", "magalpha_cal")


def _motor_comparison(results: dict) -> dict:
    """Orders predicted by the motor's pole pairs / slots vs the strongest measured ones."""
    out = {}
    for name in ("odrive_nocomp", "odrive_comp"):
        d = results[name]
        spec = d["spectrum"]
        orders = np.asarray(spec["orders"])
        before = np.asarray(spec["before"])
        top = orders[np.argsort(before)[::-1][:10]].tolist()
        p, s = d["base"]["pole_pairs"], d["base"]["stator_slots"]
        pred = candidate_orders(p, s, int(orders.max()))
        predicted = sorted(set().union(*pred.values()))
        out[name] = {
            "strongest_measured_orders": top,
            "predicted_orders_by_effect": {k: v[:12] for k, v in pred.items()},
            "measured_in_predicted": [int(o) for o in top if o in predicted],
            "measured_not_predicted": [int(o) for o in top if o not in predicted],
            "rms_before_rad": d["rms_before"],
        }
    a, b = results["odrive_nocomp"], results["odrive_comp"]
    out["comp_vs_nocomp"] = {
        "rms_before_ratio": b["rms_before"] / a["rms_before"],
        "note": "anti-cogging compensation cuts the base-model residual of the angle by this "
        "factor; the orders it removes are the pole-pair multiples (magnet asymmetry) and slot "
        "multiples (coil mismatch / cogging) the finder names on the uncompensated record",
    }
    return out


def _interferometer_comparison(results: dict) -> dict:
    out = {}
    for name in ("nmm_x", "nmm_y"):
        d = results[name]
        final = d["effects"][-1]["heldout_rms_after"] if d["effects"] else d["heldout_rms_before"]
        out[name] = {
            "heydemann_heldout_rms": d["heydemann"]["heldout_rms"],
            "encdesign_heldout_rms": final,
            "improvement_over_heydemann": 1.0 - final / d["heydemann"]["heldout_rms"],
            "unit": d["unit"],
        }
    return out


def twin_comparison(first: dict, second: dict) -> dict:
    """A motor record against its twin recorded later (``_0`` vs ``_1``): named effects,
    held-out RMS and the segments excluded from each (diagnosis JSON documents)."""

    def names(d):
        return [e["name"] for e in d["effects"]]

    return {
        "names_first": names(first),
        "names_second": names(second),
        "same_names": names(first) == names(second),
        "heldout_rms_before_rad": [first["heldout_rms_before"], second["heldout_rms_before"]],
        "heldout_rms_final_rad": [first["heldout_rms_final"], second["heldout_rms_final"]],
        "excluded_first": first["excluded_segments"],
        "excluded_second": second["excluded_segments"],
    }


def sensor_summary(d: dict) -> dict:
    """What a metrologist reads off a sensor-against-reference diagnosis: verdict, the
    sensor's dominant orders (rad, with standard errors), the direction offset where the
    record has both directions (rad), and the quantization of sensor and reference."""
    sens = d.get("sensor") or {}
    hyst = [e for e in d["effects"] if e["name"] == "direction_hysteresis"]

    def lattice(key):
        lat = sens.get(key) or {}
        return (
            {"lsb_rad": lat["lsb_rad"], "bits_per_turn": lat["bits_per_turn"]}
            if lat.get("lsb_rad")
            else None
        )

    return {
        "verdict": d["verdict"],
        "names": [e["name"] for e in d["effects"]],
        "directions": sens.get("directions"),
        "dominant_orders": [
            {k: o[k] for k in ("order", "amplitude_rad", "se_rad", "share")}
            for o in sens.get("dominant_orders", [])[:4]
        ],
        "direction_offset_rad": hyst[0]["params"]["hysteresis_rad"] if hyst else None,
        "direction_offset_confounded_with": [c["name"] for c in hyst[0]["confounded_with"]]
        if hyst
        else [],
        "sensor_quantization": lattice("sensor_lattice"),
        "reference_quantization": lattice("reference_lattice"),
        "not_testable": [n["name"] for n in d.get("not_testable", [])],
    }


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    p.add_argument("--data", type=Path, default=DATA, help="folder with the recordings")
    args = p.parse_args(argv)
    names = QUICK if args.quick else RECORDINGS
    missing = [n for n in names if not (args.data / f"{n}.toml").is_file()]
    if missing:
        p.error(f"--data {args.data}: no {', '.join(m + '.toml' for m in missing)}")
    results, rows, figures = {}, [], []
    for i, name in enumerate(names, 1):
        t0 = time.perf_counter()
        print(f"[{i}/{len(names)}] diagnosing {name} …", file=sys.stderr, flush=True)
        rec = load_recording(args.data / f"{name}.toml")
        d = diagnose(rec, plots=None if args.no_plots else args.out / name).doc
        results[name] = d
        figures += [Path(x) for x in d.get("plots", [])]
        rows.append(
            {
                "name": name,
                "kind": d["kind"],
                "verdict": d["verdict"],
                "rms_before": d["rms_before"],
                "heldout_rms_before": d["heldout_rms_before"],
                "unit": d["unit"],
                "excluded_segments": d["excluded_segments"],
                "effects": [
                    {
                        k: e.get(k)
                        for k in (
                            "name",
                            "params",
                            "rms_after",
                            "heldout_rms_after",
                            "heldout_improvement",
                            "explanation",
                        )
                    }
                    for e in d["effects"]
                ],
                "unexplained": d["unexplained"],
                "rejected": d.get("rejected", []),
                "seconds": time.perf_counter() - t0,
            }
        )
        print(d["report"], file=sys.stderr)
    summary = {"recordings": rows}
    if not args.quick:
        summary["interferometer_vs_heydemann"] = _interferometer_comparison(results)
        summary["motor_orders"] = _motor_comparison(results)
        summary["motor_twins"] = {b: twin_comparison(results[a], results[b]) for a, b in TWINS}
        summary["sensors"] = {n: sensor_summary(results[n]) for n in SENSORS}
    if not args.no_plots:
        figures.append(_summary_plot(rows, args.out))
    write_results(args, NAME, summary, figures)
    return 0


def _summary_plot(rows: list[dict], out: Path) -> Path:
    ncol = min(len(rows), 3)
    nrow = -(-len(rows) // ncol)
    fig, ax = new_figure(nrow, ncol, figsize=(3.6 * ncol, 3.4 * nrow))
    ax = np.atleast_1d(ax).ravel()
    for a in ax[len(rows) :]:
        a.set_visible(False)
    for a, row in zip(ax, rows):
        names = ["base"] + [e["name"] for e in row["effects"]]
        held = [row["heldout_rms_before"]] + [e["heldout_rms_after"] for e in row["effects"]]
        a.bar(range(len(names)), held, color=["0.6"] + ["C0"] * (len(names) - 1))
        a.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
        unit = row["unit"]
        extra = "\n+ unexplained structure" if row["unexplained"] else ""
        a.set(title=f"{row['name']}: {row['verdict']}{extra}", ylabel=f"held-out RMS ({unit})")
    return save_figure(fig, out, "real-recordings-summary.png")


if __name__ == "__main__":
    raise SystemExit(main())
