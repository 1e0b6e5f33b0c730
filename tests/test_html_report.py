"""The HTML diagnosis report: one recording of each kind (multihead, one sensor against a
reference, motion, quadrature, sds) rendered; every item is in it, every figure is an
embedded PNG, nothing refers outside the file; the CLI writes it."""

from __future__ import annotations

import base64
import html
import re
from html.parser import HTMLParser
from pathlib import Path

import jax
import numpy as np
import pytest

from encdesign import load_recording
from encdesign.cli import main as cli_main
from encdesign.diagnose.engine._document import nuisance_rows
from encdesign.diagnose.engine._html import fitted_curves, render_html, report_inputs
from encdesign.diagnose.engine._html_discovery import discovered_terms, spectrum_data
from encdesign.io._recording import write_recording
from encdesign.simulate import simulate_plan as simulate
from encdesign.simulate import simulate_quadrature, write_concealed_sds
from tests.helpers import shared_diagnosis

PLAN = {"per_run_zeros": True, "transient": True, "glitches": 1, "amplitude": 1.0}


def _record(kind: str, tmp_path):
    """A small recording of ``kind`` with one effect, a transient start and a glitch."""
    rng = np.random.default_rng(11)
    if kind == "multihead":
        plan = dict(PLAN, kind=kind, case="single", effects=["beam_tilt_axial"], n_heads=3)
        plan.update(radius_m=0.05, lines=5000, theta_ref=True, n_runs=1, turns=1.0)
        return simulate(rng, plan)[0]
    if kind == "sensor":
        plan = dict(PLAN, kind=kind, case="single", effects=["interpolation_error"])
        plan.update(sensor="magnetic", periods=21, n_runs=1, both_directions=False, turns=1.0)
        return simulate(rng, plan)[0]
    if kind == "motion":
        plan = dict(PLAN, kind=kind, case="single", effects=["cogging"], n_runs=1, turns=2.0)
        return simulate(rng, plan)[0]
    if kind == "quadrature":
        plan = {"case": "single", "effects": ["signal_shape"], "amplitude": 1.0}
        try:
            return simulate_quadrature(rng, plan)[0]
        except (KeyError, TypeError):  # the plan's keys: the generator's own draw
            from encdesign.simulate._conceal_bench import draw_quadrature_plan

            return simulate_quadrature(rng, draw_quadrature_plan(rng, "single"))[0]
    rec, _ = write_concealed_sds(
        tmp_path / "sds.toml",
        key=jax.random.key(3),
        effect="sensor_delay_step",
        concealment="clear",
        n_runs=8,
    )
    return rec


class _Parse(HTMLParser):
    def __init__(self):
        super().__init__()
        self.ids: set[str] = set()
        self.imgs: list[str] = []
        self.refs: list[str] = []
        self.tags: set[str] = set()

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.add(tag)
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "img":
            self.imgs.append(a.get("src", ""))
        for k in ("href", "src"):
            if k in a and tag != "img":
                self.refs.append(a[k])


FIGURES = ("fig-time", "fig-spectrum", "fig-heads", "fig-fitted", "fig-before-after")
SECTIONS = ("verdict", "summary", "noise", "gof", "effects", "alternatives", "nuisances")


@pytest.mark.parametrize("kind", ["multihead", "sensor", "motion", "quadrature", "sds"])
def test_report_shows_every_item(kind, tmp_path):
    d = shared_diagnosis(_record(kind, tmp_path))  # multihead's: also the notebook test's
    text = render_html(d)
    doc, rows = report_inputs(d)
    assert rows is not None and rows["base_resid"].shape == rows["final_resid"].shape
    p = _Parse()
    p.feed(text)
    assert set(SECTIONS) <= p.ids and set(FIGURES) <= p.ids, sorted(p.ids)
    # nothing outside the file: no script, no stylesheet link, no URL anywhere
    assert "script" not in p.tags and "link" not in p.tags and p.refs == []
    bare = re.sub(r'src="data:image/png;base64,[A-Za-z0-9+/=]+"', "", text)
    assert not re.search(r"(https?:)?//[a-z0-9]|url\(|@import", bare, re.I)
    # each drawn figure is a decodable PNG (the fitted-effect one only with effects)
    n_fig = len(FIGURES) - (0 if doc["effects"] else 1) + (1 if discovered_terms(doc) else 0)
    assert len(p.imgs) == n_fig
    for src in p.imgs:
        head, data = src.split(",", 1)
        assert head == "data:image/png;base64"
        assert base64.b64decode(data)[:8] == b"\x89PNG\r\n\x1a\n"
    assert f'class="verdict v-{doc["verdict"]}"' in text
    for s in doc["noise"]["per_channel"]:
        assert f"{s:.4g}" in text
    assert f"{doc['goodness_of_fit']['p_value']:.4g}" in text
    # each effect: its parameters with their standard errors, its held-out gain
    prev = doc["heldout_rms_before"]
    for e in doc["effects"]:
        assert f". {e['name']}</h3>" in text
        for name, q in e["params"].items():
            assert f"<td>{name}</td>" in text
            if np.ndim(q["value"]) == 0 and q["se"] is not None:
                assert f"{q['value']:.6g} ± {q['se']:.3g}" in text
        assert f"{prev - e['heldout_rms_after']:.4g}" in text
        prev = e["heldout_rms_after"]
    # alternatives and refusals, one row each
    alt = text.split('id="alternatives"', 1)[1].split("<h2", 1)[0]
    for r in doc["rejected"] + doc["not_testable"]:
        assert f"<td>{r['name']}</td>" in alt
    assert (
        alt.count("<tr>") - 1
        == len(doc["rejected"])
        + len(doc["not_testable"])
        + sum(len(e.get("confounded_with") or []) for e in doc["effects"])
        + sum(len(e.get("alternatives") or []) for e in doc["effects"] if e.get("doubt"))
        or alt.count("<tr>") == 0
    )
    # the fitted-effect figure: one curve per fitted named effect, its own contribution
    # from the typed results (not the sum of all)
    fitted = [e.name for e in d.effects if e.delta_bic is not None]
    assert set(d.plot_data.effect_contributions) == set(fitted)
    if fitted:
        curves = fitted_curves(doc, rows)
        assert [n for n, _ in curves] == fitted
        for name, c in curves:
            assert c is rows["effects"][name] and c.shape == rows["base_resid"].shape
            assert np.any(c[rows["keep"]] != 0.0)
        assert "one curve each: " + ", ".join(fitted) in text
    # one row formatter for the nuisances: the text report's lines and the HTML table's rows
    for what, run, t, detail in nuisance_rows(doc):
        assert f"{what}: run {run} t {t} s: {detail}" in doc["report"]
        assert f"<td>{html.escape(what)}</td><td>{html.escape(run)}</td>" in text
    if kind in ("multihead", "sensor", "motion"):  # these benches start with a transient
        assert doc["excluded_segments"] and "excluded" in text


def test_cli_writes_the_report(tmp_path, capsys):
    rng = np.random.default_rng(2)
    phi = rng.uniform(0, 2 * np.pi, 600)
    sa = np.cos(phi) + rng.normal(0, 1e-3, 600)
    sb = 0.98 * np.sin(phi) + rng.normal(0, 1e-3, 600)
    write_recording(tmp_path / "q.toml", "quadrature", {"sa": sa, "sb": sb})
    out = tmp_path / "r.html"
    rc = cli_main(
        [
            "diagnose",
            str(tmp_path / "q.toml"),
            "--json",
            str(tmp_path / "d.json"),
            "--html",
            str(out),
            "--quiet",
        ]
    )
    assert rc == 0 and out.read_text().startswith("<!DOCTYPE html>")
    assert "wrote " + str(out) in capsys.readouterr().err
    # an output that is the input is refused before any work (exit 2)
    rc = cli_main(
        [
            "diagnose",
            str(tmp_path / "q.toml"),
            "--json",
            str(tmp_path / "e.json"),
            "--html",
            str(tmp_path / "q.toml"),
        ]
    )
    assert rc == 2


def test_nuisance_rows_format_each_kind_once():
    doc = {
        "unit": "rad",
        "excluded_segments": [
            {"run": 0, "t_start_s": 0.0, "t_end_s": 1.25, "n_rows": 40, "reason": "start-up"}
        ],
        "glitches": [{"run": 1, "t_s": 2.5, "channel": "h1"}],
        "count_jumps": [{"run": 1, "t_s": 3.0, "channel": "h0", "size": 1e-3}],
        "gaps": [{"run": 2, "t_s": 4.0, "duration_s": 0.75}],
    }
    assert nuisance_rows(doc) == [
        ("excluded", "0", "0..1.25", "40 rows: start-up"),
        ("glitch", "1", "2.5", "channel h1"),
        ("count jump", "1", "3", "channel h0, size 0.001 rad"),
        ("gap", "2", "4", "for 0.75 s"),
    ]


def test_diagnosis_renders_in_a_notebook(tmp_path):
    """``Diagnosis._repr_html_``: the report's verdict line and tables (a fragment with its
    own scoped style, no figures), every value from the document escaped."""
    d = shared_diagnosis(_record("multihead", tmp_path))
    doc = d.to_json()
    h = d._repr_html_()
    assert f'<span class="verdict v-{doc["verdict"]}">{doc["verdict"]}</span>' in h
    assert f"status {html.escape(doc['status'])}" in h and f"<b>{doc['kind']}</b>" in h
    assert f"<td>{doc['rms_before']:.4g}</td>" in h
    assert f"{doc['goodness_of_fit']['p_value']:.4g}" in h
    for s in doc["noise"]["per_channel"]:
        assert f"{s:.4g}" in h
    assert doc["effects"]  # the bench hides one effect: its name and held-out RMS are shown
    for e in doc["effects"]:
        assert f". {e['name']}</h3>" in h and f"{e['heldout_rms_after']:.4g}" in h
    p = _Parse()
    p.feed(h)
    assert {"summary", "effects", "alternatives", "nuisances"} <= p.ids
    assert not p.imgs and not {"html", "body", "script"} & p.tags  # a fragment, no figures
    style = h.split("<style>", 1)[1].split("</style>", 1)[0]
    rules = [r.strip() for r in style.split("}") if r.strip()]
    assert rules and all(
        all(sel.strip().startswith(".encdesign-result") for sel in r.split("{")[0].split(","))
        for r in rules
    )  # the notebook's own styles are left alone
    # a hostile recording name and effect explanation are shown as text
    bad = '<img src=x onerror="alert(1)">'
    doc2 = dict(doc, recording=bad)
    doc2["effects"] = [dict(doc["effects"][0], explanation="<script>x</script>")]
    doc2["effects"] += doc["effects"][1:]
    h2 = type(d).from_json(doc2)._repr_html_()
    assert html.escape(bad) in h2 and bad not in h2
    assert "&lt;script&gt;x&lt;/script&gt;" in h2 and "<script>" not in h2


MOTEUS = Path(__file__).resolve().parent.parent / "data" / "real" / "moteus_cal.toml"


def test_report_shows_the_discovered_model_where_it_is():
    """On the measured moteus record (a sensor against a commanded reference): the located
    lines sit at shaft orders near 126 and 252, beyond the base model's order limit. The
    spectrum figure reaches them (and shows the line there), the discovered model is shown
    with a figure of each term over the residual in its own frame, and each refusal row
    carries its selection round (a candidate tried in several rounds: once per round)."""
    d = shared_diagnosis(load_recording(MOTEUS))  # also test_reference's measured-sensor test
    doc, rows = report_inputs(d)
    located = [o for f in doc["unexplained"] for o in f["where"].get("orders") or []]
    assert located and max(located) > 200, located
    o, before, _ = spectrum_data(doc, rows)
    assert o.max() >= max(located), (o.max(), located)
    # the strongest located line stands out of its neighbourhood in the figure's spectrum
    lines = [f for f in doc["unexplained"] if f["where"].get("orders")]
    top = round(max(lines, key=lambda f: f["rms"])["where"]["orders"][0])
    i = int(np.flatnonzero(o == top)[0])
    assert before[i] > 3 * np.median(before[max(i - 20, 0) : i + 20]), before[i - 3 : i + 4]
    text = render_html(d)
    p = _Parse()
    p.feed(text)
    assert {"fig-spectrum", "fig-discovered"} <= p.ids, sorted(p.ids)
    terms = discovered_terms(doc)
    assert terms and "discovered model (outside the catalog)" in text
    for t in terms:
        assert html.escape(t["reading"]) in text
        assert f"{t['heldout_gain_chi2']:.4g}" in text
    fig = text.split('id="fig-discovered"', 1)[1].split("</figure>", 1)[0]
    assert fig.count("data:image/png;base64,") == 1
    # refusals: every row names its round; a (candidate, round) pair at most once
    alt = text.split('id="alternatives"', 1)[1].split("<h2", 1)[0]
    rows_ = re.findall(r"<tr>(.*?)</tr>", alt, re.S)[1:]
    rej = [r for r in rows_ if "<td>rejected</td>" in r]
    assert len(rej) == len(doc["rejected"]) > 0
    pairs = []
    for r in rej:
        cells = re.findall(r"<td[^>]*>(.*?)</td>", r, re.S)
        assert re.fullmatch(r"round \d+|after selection", cells[-1]), cells
        pairs.append((cells[0], cells[-1]))
    assert len(set(pairs)) == len(pairs), pairs
    # the text report: where each term sits and the nearest catalog effects
    assert "    on heads " in doc["report"] and "directions " in doc["report"]
    assert "nearest catalog effects (not enough): " in doc["report"]
    for r in doc["rejected"]:
        rnd = f"round {r['round']}" if r.get("round") is not None else "after selection"
        assert f"rejected {r['name']} ({rnd}): " in doc["report"]
