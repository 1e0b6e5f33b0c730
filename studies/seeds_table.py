"""The seeds' results table: docs/seeds.md's rows rendered from one machine-readable source.

``docs/seeds_rows.json`` holds every row of ``docs/seeds.md`` (the seed's result, its value,
encdesign's value, the label) and, for every row with numbers, a ``check``: the model value
and its uncertainty, the seed's value with its σ or its bound, and where the numbers come
from (``source``: ``"cal:<instrument>/<figure key>"`` for the ``seed-calibration`` study,
``"cf:<key>"`` for its closed forms, ``"<study>:<JSON key>"`` for another study's summary).
A row that quotes several of the seed's numbers holds a list of checks. A prediction row
without numbers must say why: ``qualitative: "no number in the seed: <reason>"``.
This study checks every label against its numbers with the one agreement rule (a value
agrees within 2σ, σ² = σ_model² + σ_seed²; a bound "≤ b" is met when model − 2σ_model ≤ b:
a bound is a bound, never a Gaussian), optionally refreshes the numbers from a
``seed-calibration`` JSON (``--from-cal F``), and renders the tables into ``docs/seeds.md``
between its ``<!-- seeds-rows … -->`` markers (``--write-doc``). The encdesign cell of a
checked row may carry ``{model}``, ``{model_sd}``, ``{z}``, ``{excess}`` fields (Python
format syntax), filled from the check, so each number is written once.

Labels: ``agrees`` / ``disagrees`` (a genuine prediction: not fitted, not a function of a
fitted figure), ``fitted`` (a training figure), ``input``, ``not simulated``, and, listed
apart with their verdict, ``arithmetic`` (the seed's own conversions and counts),
``constant`` (the model gives it whatever its parameters), ``conversion`` (a unit conversion
of a fitted parameter), ``bound`` (a seed bound that every parameter set meeting the fit
meets), ``hypothesis`` (a statement of the seed's text tested against fitted parameters).
"""

import json
import math
import re
import sys
from pathlib import Path

from encdesign.io import study_parser, write_results

NAME = "seeds-table"
ROOT = Path(__file__).resolve().parents[1]
ROWS_PATH = ROOT / "docs" / "seeds_rows.json"
DOC_PATH = ROOT / "docs" / "seeds.md"
PREDICTION_LABELS = ("agrees", "disagrees")
APART_LABELS = ("arithmetic", "constant", "conversion", "bound", "hypothesis")
OTHER_LABELS = ("fitted", "input", "not simulated")
LABELS = PREDICTION_LABELS + APART_LABELS + OTHER_LABELS
SEEDS = ("000", "001", "002")
HEADER = (
    "| # | seed result (section) | seed value | encdesign value [ref, key] | label |\n"
    "| --- | --- | --- | --- | --- |"
)


def agreement(model: float, model_sd: float, seed: float, seed_sigma: float, bound) -> dict:
    """A value agrees within 2σ (σ² = σ_model² + σ_seed²); a bound "≤ b" is met when
    model − 2σ_model ≤ b, a bound "≥ b" (``"lower"``: the seed's "more than", "slightly more
    than") when model + 2σ_model ≥ b (the seed's σ is not used: a bound is not a Gaussian).
    The same rule as ``seed-calibration``'s for values and upper bounds (its tests check both)."""
    if bound == "upper":
        excess = (model - seed) / model_sd if model_sd > 0 else None
        return {"agrees": model - 2 * model_sd <= seed, "z": None, "excess": excess}
    if bound == "lower":
        excess = (seed - model) / model_sd if model_sd > 0 else None
        return {"agrees": model + 2 * model_sd >= seed, "z": None, "excess": excess}
    if bound is not None:
        raise ValueError(f"bound {bound!r}: expected None, 'upper' or 'lower'")
    comb = math.hypot(model_sd, seed_sigma)
    if comb == 0:
        return {"agrees": model == seed, "z": None, "excess": None}
    z = (model - seed) / comb
    return {"agrees": abs(z) <= 2, "z": z, "excess": None}


def load(path: Path = ROWS_PATH) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the seeds' rows table is not there (a repository file)")
    data = json.loads(path.read_text(encoding="utf-8"))
    if data.get("schema") != "encdesign-seeds-rows/1":
        raise ValueError(f"{path}: schema {data.get('schema')!r}, expected encdesign-seeds-rows/1")
    return data


def checks(row: dict) -> list[dict]:
    """The row's numbers: ``check`` is one comparison or a list of them (a row that quotes
    several of the seed's numbers, e.g. a count of measurements, equations and unknowns)."""
    c = row.get("check")
    if c is None:
        return []
    return list(c) if isinstance(c, list) else [c]


def _one(c: dict) -> dict:
    return agreement(
        float(c["model"]),
        float(c.get("model_sd", 0.0)),
        float(c["seed"]),
        float(c.get("seed_sigma", 0.0)),
        c.get("bound"),
    )


def verdict(row: dict) -> dict | None:
    """The row's verdict: it agrees when every one of its comparisons does; ``z`` and
    ``excess`` are the first comparison's (the one the encdesign cell quotes as ``{z}``)."""
    vs = [_one(c) for c in checks(row)]
    if not vs:
        return None
    return {"agrees": all(v["agrees"] for v in vs), "z": vs[0]["z"], "excess": vs[0]["excess"]}


QUALITATIVE_PREFIX = "no number in the seed: "


def check_row(row: dict) -> list[str]:
    """Every way the row's label contradicts its numbers (empty: consistent)."""
    rid, label = row.get("id", "?"), row.get("label")
    bad = []
    if label not in LABELS:
        return [f"row {rid}: label {label!r} not one of {LABELS}"]
    v = verdict(row)
    cs = checks(row)
    for c in cs:
        if c.get("bound") in ("upper", "lower") and "seed_sigma" in c:
            bad.append(f"row {rid}: a bound carries a seed_sigma (a bound is not a Gaussian)")
        if not c.get("source"):
            bad.append(f"row {rid}: a check without its source (study and key)")
    q = row.get("qualitative")
    if q is not None:
        reason = str(q)[len(QUALITATIVE_PREFIX) :] if str(q).startswith(QUALITATIVE_PREFIX) else ""
        if len(reason.strip()) < 10:
            bad.append(
                f"row {rid}: qualitative {q!r}: expected {QUALITATIVE_PREFIX!r} and the reason"
            )
        if v is not None:
            bad.append(f"row {rid}: qualitative, yet it carries numbers (check)")
    if label in PREDICTION_LABELS:
        if v is None:
            if q is None:
                bad.append(f"row {rid}: '{label}' without numbers (check) or a qualitative reason")
        elif v["agrees"] != (label == "agrees"):
            bad.append(f"row {rid}: label '{label}' but the numbers say {_say(v)}")
        for c in cs:
            if c.get("kind") not in (None, "predict"):
                bad.append(f"row {rid}: '{label}' on a {c.get('kind')} figure (not a prediction)")
    if row.get("verdict") and v is None:
        bad.append(f"row {rid}: a verdict without the numbers (check) behind it")
    if label in APART_LABELS:
        if v is None:
            bad.append(f"row {rid}: '{label}' without the numbers (check) behind its verdict")
        else:
            want = "agrees" if v["agrees"] else "disagrees"
            if row.get("verdict") != want:
                bad.append(f"row {rid}: verdict {row.get('verdict')!r} but the numbers say {want}")
    if label == "fitted" and any(c.get("kind") != "train" for c in cs):
        bad.append(f"row {rid}: 'fitted' on a non-training figure")
    if label == "disagrees" and not row.get("reason"):
        bad.append(f"row {rid}: 'disagrees' without the reason")
    return bad


def _say(v: dict) -> str:
    if v["z"] is not None:
        return f"z {v['z']:+.2f} ({'agrees' if v['agrees'] else 'disagrees'})"
    return "the bound is " + ("met" if v["agrees"] else "exceeded beyond 2σ_model")


def _cell(row: dict) -> str:
    text = row["encdesign"]
    cs = checks(row)
    if cs:
        fields = {}
        for i, c in enumerate(cs):
            v = _one(c)
            f = {
                "model": c["model"],
                "model_sd": c.get("model_sd", 0.0),
                "z": v["z"] if v["z"] is not None else float("nan"),
                "excess": v["excess"] if v["excess"] is not None else float("nan"),
            }
            fields.update({f"{k}{i}": x for k, x in f.items()})
            if i == 0:
                fields.update(f)
        text = text.format(**fields)
    return text


def _label_cell(row: dict) -> str:
    s = row["label"]
    if row.get("verdict"):
        s += f" ({row['verdict']})"
    if row.get("qualitative"):
        s += f" (qualitative: {row['qualitative']})"
    if row.get("reason"):
        s += f": {row['reason']}"
    return s


def render_rows(data: dict, seed: str) -> str:
    lines = [HEADER]
    for r in data["rows"]:
        if r["id"].split(".")[0] != str(int(seed)):
            continue
        cells = [r["id"], r["result"], r["seed_value"], _cell(r), _label_cell(r)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def counts(data: dict) -> dict:
    out = {s: {k: 0 for k in LABELS} for s in SEEDS}
    for r in data["rows"]:
        out[f"{int(r['id'].split('.')[0]):03d}"][r["label"]] += 1
    return out


def render_counts(data: dict) -> str:
    c = counts(data)
    used = [k for k in LABELS if any(c[s][k] for s in SEEDS)]
    lines = ["| seed | " + " | ".join(used) + " | rows |", "| --- " * (len(used) + 2) + "|"]
    total = {k: 0 for k in used}
    for s in SEEDS:
        lines.append(
            f"| {s} | " + " | ".join(str(c[s][k]) for k in used) + f" | {sum(c[s].values())} |"
        )
        for k in used:
            total[k] += c[s][k]
    lines.append(
        "| all | " + " | ".join(str(total[k]) for k in used) + f" | {sum(total.values())} |"
    )
    return "\n".join(lines)


def render_misses(data: dict) -> str:
    lines = [
        "| row | before (issue 42) | physics added | parameters it cost | after | label now |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for m in data["misses"]:
        lines.append(
            f"| {m['row']} | {m['before']} | {m['added']} | {m['cost']} | {m['after']} |"
            f" {m['label_now']} |"
        )
    return "\n".join(lines)


def render_doc(text: str, data: dict) -> str:
    """``text`` with every block between ``<!-- seeds-rows X -->`` and
    ``<!-- /seeds-rows -->`` replaced by its rendering (X: 000, 001, 002, counts, misses)."""
    blocks = {s: render_rows(data, s) for s in SEEDS}
    blocks["counts"] = render_counts(data)
    blocks["misses"] = render_misses(data)
    pat = re.compile(r"(<!-- seeds-rows (\w+) -->\n)(.*?)(<!-- /seeds-rows -->)", re.S)
    found = set()

    def sub(m):
        found.add(m.group(2))
        if m.group(2) not in blocks:
            raise ValueError(f"docs/seeds.md: unknown block {m.group(2)!r}")
        return m.group(1) + blocks[m.group(2)] + "\n" + m.group(4)

    out = pat.sub(sub, text)
    missing = set(blocks) - found
    if missing:
        raise ValueError(f"docs/seeds.md: no marker for block(s) {sorted(missing)}")
    return out


def _closed(closed: dict, path: str):
    """``closed_forms[path]``, where a dotted path reaches into a nested entry
    (``s001_closure_counts.N12_complete.equations``)."""
    if path in closed:
        return closed[path]
    for k in sorted(closed, key=len, reverse=True):  # keys may hold dots themselves
        if path.startswith(k + ".") and isinstance(closed[k], dict):
            return _closed(closed[k], path[len(k) + 1 :])
    raise KeyError(path)


def update_from_calibration(data: dict, cal: dict) -> list[str]:
    """Copy model values and uncertainties of ``cal:`` rows from a ``seed-calibration``
    summary; returns the rows updated."""
    figs = {f"{r['instrument']}/{x['key']}": x for r in cal["instruments"] for x in r["figures"]}
    done = []
    closed = cal.get("closed_forms", {})
    for row in data["rows"]:
        for c in checks(row):
            src = str(c.get("source", ""))
            if src.startswith("cf:"):  # the seed's arithmetic, recomputed by the study
                try:
                    value = _closed(closed, src[3:])
                except KeyError:
                    raise ValueError(
                        f"row {row['id']}: source {src!r} not in closed_forms"
                    ) from None
                c["model"], c["model_sd"] = float(value), 0.0
                done.append(row["id"])
                continue
            if not src.startswith("cal:"):
                continue
            key = src[4:]
            if key not in figs:
                raise ValueError(f"row {row['id']}: source {key!r} not in the calibration JSON")
            x = figs[key]
            c["model"], c["model_sd"], c["kind"] = x["model"], x["model_sd"] or 0.0, x["kind"]
            done.append(row["id"])
    data["calibration"] = {
        k: cal[k] for k in ("predicted_within_2sigma", "predicted_total") if k in cal
    }
    return done


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    p.add_argument("--rows", type=Path, default=ROWS_PATH, help="the rows JSON")
    p.add_argument("--from-cal", type=Path, default=None, help="seed-calibration JSON to copy")
    p.add_argument("--write-doc", action="store_true", help="render into docs/seeds.md")
    args = p.parse_args(argv)
    data = load(args.rows)
    updated = []
    if args.from_cal is not None:
        updated = update_from_calibration(data, json.loads(args.from_cal.read_text()))
        args.rows.write_text(json.dumps(data, ensure_ascii=False, indent=1) + "\n")
    problems = [b for r in data["rows"] for b in check_row(r)]
    if args.write_doc:
        DOC_PATH.write_text(render_doc(DOC_PATH.read_text(encoding="utf-8"), data))
    summary = {
        "study": NAME,
        "rows": len(data["rows"]),
        "counts": counts(data),
        "updated_from_calibration": updated,
        "label_problems": problems,
    }
    for b in problems:
        print(f"[{NAME}] {b}", file=sys.stderr)
    write_results(args, NAME, summary, [])
    return 1 if problems else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
