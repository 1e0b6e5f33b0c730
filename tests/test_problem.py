"""Problem statements: TOML validation, bad files refused, solving, case recording."""

import math

import jax
import jax.numpy as jnp
import pytest

from encdesign import EncdesignInputError
from encdesign.cli import main
from encdesign.design._cases import CaseRecorder, read_cases, write_cases
from encdesign.design._drivers import (
    BFGS,
    DRIVERS,
    LBFGSB,
    DriverStatus,
    Grid,
    LatinHypercube,
    LevenbergMarquardt,
)
from encdesign.design._problem import ProblemObjective, VariableInfo, load_problem, parse_problem
from encdesign.design._solve import check_gradients, solve_problem, sweep_problem


def _quadratic_build(problem, discrete):
    """f = (x - c)^2 + 0.1 (y + 1)^2 + k * 0.01, c = model["c"] + 0.1 * k (k discrete)."""
    k = discrete.get("k", 0)
    c = problem.model["c"] + 0.1 * k

    def evaluate(x):
        xv = x.get("x", 0.0)
        yv = x.get("y", 0.0)
        f = (xv - c) ** 2 + 0.1 * (yv + 1.0) ** 2 + 0.01 * k
        return {"f": f, "g": xv + yv, "residuals": jnp.stack([xv - c, 0.3 * (yv + 1.0)])}

    return evaluate


REGISTRY = {
    "quad": ProblemObjective(
        name="quad",
        doc="analytic test objective",
        variables={
            "x": VariableInfo("m"),
            "y": VariableInfo("rad"),
            "k": VariableInfo("1", discrete=True, integer=True, lower=0),
        },
        model={"c": 0.5},
        outputs=("f", "g", "residuals"),
        build=_quadratic_build,
    )
}


def _problem(**over):
    data = {
        "problem": {"name": "t", "objective": "quad", "seed": 3},
        "model": {"c": 0.5},
        "variables": {
            "x": {"units": "mm", "start": 100.0, "lower": -2000.0, "upper": 2000.0},
            "y": {"units": "deg", "start": 0.0, "lower": -90.0, "upper": 90.0},
        },
        "driver": {"kind": "lbfgsb", "max_steps": 200},
    }
    for k, v in over.items():
        data[k] = v
    return data


def test_units_converted_to_si():
    p = parse_problem(_problem(), REGISTRY)
    x, y = p.variables
    assert x.start == pytest.approx(0.1) and x.upper == pytest.approx(2.0)
    assert y.lower == pytest.approx(-math.pi / 2)
    assert p.seed == 3 and p.driver == LBFGSB(max_steps=200)


@pytest.mark.parametrize("kind", ["bfgs", "lm"])  # lbfgsb: test_cli_optimize_and_check_gradients
def test_gradient_drivers_solve(kind):
    p = parse_problem(_problem(driver={"kind": kind}), REGISTRY)
    r = solve_problem(p)
    assert r.status == "success", r.message
    assert r.best.inputs["x"] == pytest.approx(0.5, abs=1e-6)
    assert r.best.inputs["y"] == pytest.approx(-1.0, abs=1e-5)


def test_enumeration_wrapped_around_continuous_optimum(tmp_path):
    vars_ = _problem()["variables"] | {"k": {"values": [0, 1, 2]}}
    p = parse_problem(_problem(variables=vars_, driver={"kind": "bfgs"}), REGISTRY)
    with CaseRecorder(tmp_path / "c.jsonl") as rec:
        r = solve_problem(p, recorder=rec)
    assert r.status == "success"
    assert r.best.discrete == {"k": 0}  # the 0.01 k term makes k = 0 best
    assert [res.inputs["x"] for res in r.results] == pytest.approx([0.5, 0.6, 0.7], abs=1e-6)
    back = read_cases(tmp_path / "c.jsonl")
    assert back == rec.cases and len(back) == 3


def test_constraint_is_respected_or_reported():
    p = parse_problem(
        _problem(constraints={"g": {"upper": -1.0}}, driver={"kind": "bfgs"}), REGISTRY
    )
    r = solve_problem(p)
    assert r.status == "success", r.results[0].message
    # the constrained optimum of (x - .5)^2 + .1 (y + 1)^2 on x + y = -1
    assert r.best.inputs["x"] == pytest.approx(0.5 / 1.1, abs=1e-4)
    assert r.best.outputs["g"] <= -1.0 + 1e-4
    # infeasible: both bounds on g contradict the variable bounds
    p2 = parse_problem(
        _problem(constraints={"g": {"lower": 100.0}}, driver={"kind": "bfgs"}), REGISTRY
    )
    r2 = solve_problem(p2)
    assert r2.status == "failed" and r2.best is None
    assert r2.results[0].status in ("infeasible", "bounds_violated")


def test_grid_sweep_finds_known_optimum_and_records(tmp_path):
    d = _problem(sweep={"kind": "grid", "points_per_dim": 21})
    d["variables"] = {"x": {"units": "m", "start": 0.0, "lower": -1.0, "upper": 1.0}}
    p = parse_problem(d, REGISTRY)
    with CaseRecorder(tmp_path / "s.csv") as rec:
        r = sweep_problem(p, recorder=rec)
    assert r.best.inputs["x"] == pytest.approx(0.5, abs=1e-12)
    cases = read_cases(tmp_path / "s.csv")
    assert len(cases) == 21 and cases == rec.cases
    assert all(c.seed == 3 for c in cases)


def test_case_files_round_trip_exactly(tmp_path):
    with CaseRecorder(None) as rec:
        rec.record({"a": 0.1 + 0.2, "n": 3, "s": "x"}, {"v": 1e-300, "w": math.nan}, "nonfinite", 7)
        rec.record({"a": -1.0 / 3.0, "n": 4, "s": "y"}, {"v": [1.5, 2.0]}, "success", None)
    for suffix in (".jsonl", ".csv"):
        path = write_cases(tmp_path / f"c{suffix}", rec.cases)
        back = read_cases(path)
        assert back[0].inputs == rec.cases[0].inputs and back[1] == rec.cases[1]
        assert math.isnan(back[0].outputs["w"]) and back[0].outputs["v"] == 1e-300
        assert isinstance(back[0].inputs["n"], int) and back[0].seed == 7


def test_check_gradients_table():
    p = parse_problem(_problem(), REGISTRY)
    rows = check_gradients(p)
    assert {(r.output, r.variable) for r in rows} == {("f", "x"), ("f", "y")}
    assert all(r.ok for r in rows)
    fx = next(r for r in rows if r.variable == "x")
    assert fx.ad == pytest.approx(2 * (0.1 - 0.5))


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda d: d["variables"].update(z={"start": 1.0}), "unknown variable 'z'"),
        (lambda d: d["variables"]["x"].update(start=5000.0), "outside the bounds"),
        (lambda d: d.update({"yield": {"target": 1.0, "spec": 1.0}}), "infeasible yield target"),
        (
            lambda d: d.update({"yield": {"target": 0.999, "spec": 1.0, "n_builds": 100}}),
            "infeasible yield target",
        ),
        (lambda d: d["variables"].update(k={"values": [1, 2.5]}), "not an integer"),
        (lambda d: d["problem"].update(objective="nope"), "unknown objective"),
        (lambda d: d["variables"]["x"].update(units="kg"), "unknown units"),
        (lambda d: d["variables"]["y"].update(units="mm"), "not a unit of 'rad'"),
        (lambda d: d["driver"].update(kind="newton"), "unknown driver"),
        (lambda d: d["model"].update(q=1.0), "unknown model setting"),
        (lambda d: d.update(constraints={"zz": {"upper": 1.0}}), "unknown output"),
    ],
)
def test_bad_problems_are_refused(edit, needle):
    d = _problem()
    edit(d)
    with pytest.raises(EncdesignInputError, match=needle):
        parse_problem(d, REGISTRY)


BAD_POLES = """
[problem]
name = "poles"
objective = "sds_residual"

[variables.pole_pairs]
values = [5, 6.5]

[variables.n_sensors]
values = [3]
"""


def test_non_integer_pole_count_names_field(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(BAD_POLES)
    with pytest.raises(EncdesignInputError, match=r"variables\.pole_pairs\.values\[1\]"):
        load_problem(path)
    assert main(["optimize", str(path)]) == 2
    assert "not an integer" in capsys.readouterr().err
    assert path.read_text() == BAD_POLES  # input never modified


def test_cli_optimize_and_check_gradients(tmp_path, capsys):
    path = tmp_path / "p.toml"
    path.write_text(
        "[problem]\nname='sens'\nobjective='cotangent_sensitivity'\n"
        "[model]\nn_heads=3\nmax_order=9\nn_builds=0\n"
        "[variables.reference_angle]\nunits='deg'\nstart=20.0\nlower=14.0\nupper=28.0\n"
        "[driver]\nkind='lbfgsb'\n"
    )
    assert main(["check-gradients", str(path), "--json", str(tmp_path / "g.json")]) == 0
    out = capsys.readouterr().out
    assert "sensitivity" in out and "1/1 gradients agree" in out
    rc = main(
        [
            "optimize",
            str(path),
            "--quiet",
            "--cases",
            str(tmp_path / "c.csv"),
            "--json",
            str(tmp_path / "s.json"),
        ]
    )
    assert rc == 0
    cases = read_cases(tmp_path / "c.csv")
    assert len(cases) == 1 and cases[0].status == "success"
    assert 14.0 < math.degrees(cases[0].inputs["reference_angle"]) < 28.0


def _sds_problem(**model):
    return {
        "problem": {"name": "sds", "objective": "sds_layout"},
        "model": {"marks_per_rev": 120, "n_phi": 8, "n_builds": 2, "n_sensors": 3, **model},
        "variables": {
            "pole_pairs": {"values": [5]},
            "moving_azimuths": {"units": "deg", "start": [0.0, 100.0, 250.0]},
            "eccentricity_rad": {"start": 2e-3, "lower": 1e-4, "upper": 1e-2},
        },
        "driver": {"kind": "bfgs", "max_steps": 8},
    }


def test_sds_layout_problem_azimuths_and_tolerances_jointly():
    """Issue 14 item 2: sensor azimuths (a vector) and a mark tolerance are continuous
    variables of one problem, pole pairs discrete; AD gradients agree with central
    differences and a few BFGS steps lower the residual."""
    p = parse_problem(_sds_problem(), source="sds.toml")
    names = [v.name for v in p.continuous]
    assert names == [*(f"moving_azimuths[{i}]" for i in range(3)), "eccentricity_rad"]
    rows = check_gradients(p)
    assert {r.variable for r in rows} == set(names)
    assert all(r.ok for r in rows), [(r.variable, r.ad, r.fd) for r in rows]
    ecc = next(r for r in rows if r.variable == "eccentricity_rad")
    assert ecc.ad > 0  # looser centring: a larger residual
    d = _sds_problem()
    del d["variables"]["eccentricity_rad"]  # alone it would just run to its lower bound
    p = parse_problem(d, source="sds.toml")
    (r,) = solve_problem(p).results
    assert r.status in ("success", "max_steps_reached"), r.message
    ev0 = jax.jit(p.objective.build(p, {"pole_pairs": 5}))(  # compiled: eagerly, seconds
        {"moving_azimuths": jnp.radians(jnp.array([0.0, 100.0, 250.0]))}
    )
    assert r.outputs["sds_residual"] < 0.9 * float(ev0["sds_residual"])
    bad = _sds_problem()
    bad["variables"]["moving_azimuths"]["start"] = [0.0, 100.0, 100.0]
    with pytest.raises(EncdesignInputError, match=r"moving_azimuths\.start.*coincide"):
        parse_problem(bad, source="sds.toml")


def test_bound_hits_are_reported_in_optimize_and_sweep_json():
    """The optimum of x lies outside the box: L-BFGS-B ends on the bound and a grid's best
    point is on the bound; both say ``at_bound`` (in the summary JSON too), never success,
    and remain answers (issue 27)."""
    d = _problem()
    d["variables"]["x"] = {"units": "m", "start": 0.0, "lower": -1.0, "upper": 0.3}
    r = solve_problem(parse_problem(d, REGISTRY))
    assert r.status == "at_bound" and r.best is not None
    assert r.best.inputs["x"] == pytest.approx(0.3) and "upper" in r.best.message
    summary = r.summary()
    assert summary["status"] == "at_bound" and summary["best"]["status"] == "at_bound"
    d["sweep"] = {"kind": "grid", "points_per_dim": 5}
    del d["variables"]["y"]
    sw = sweep_problem(parse_problem(d, REGISTRY))
    assert sw.status == "at_bound" and sw.best.inputs["x"] == pytest.approx(0.3)
    assert "upper x" in sw.best.message
    d["variables"]["x"]["upper"] = 1.0  # the optimum 0.5 inside: plain success
    assert sweep_problem(parse_problem(d, REGISTRY)).status == "success"


@pytest.mark.parametrize("kind", sorted(DRIVERS))
def test_driver_table_parses_into_its_driver(kind):
    """Each ``[driver] kind`` becomes its driver object, with the file's settings and the
    driver's own defaults for the rest; the summary records every setting."""
    cls = DRIVERS[kind]
    name, (number, lo, _hi) = next(iter(cls.limits.items()))
    value = number(lo) + (3 if number is int else 1e-9)
    p = parse_problem(_problem(driver={"kind": kind, name: value}), REGISTRY)
    assert type(p.driver) is cls and getattr(p.driver, name) == value
    assert p.driver == cls(**{name: value})


@pytest.mark.parametrize(
    ("driver", "field", "needle"),
    [
        ({"kind": "bfgs", "gtol": 1e-8}, "driver.gtol", "not a setting of the 'bfgs' driver"),
        ({"kind": "lm", "penalty": 10.0}, "driver.penalty", "not a setting of the 'lm'"),
        ({"kind": "lbfgsb", "rtol": 1e-8}, "driver.rtol", "not a setting of the 'lbfgsb'"),
        ({"kind": "grid", "n": 5}, "driver.n", "not a setting of the 'grid' driver"),
        ({"kind": "lhs", "points_per_dim": 5}, "driver.points_per_dim", "'lhs' driver"),
        ({"kind": "lhs", "n": 0}, "driver.n", "an integer 1"),
        ({"kind": "bfgs", "max_steps": 0}, "driver.max_steps", "an integer 1"),
        ({"kind": "bfgs", "max_steps": 2.5}, "driver.max_steps", "not an integer"),
        ({"kind": "bfgs", "rtol": -1e-8}, "driver.rtol", "a finite number in"),
        ({"kind": "lbfgsb", "gtol": "small"}, "driver.gtol", "not a number"),
        ({"kind": "grid", "points_per_dim": 1}, "driver.points_per_dim", "an integer 2"),
        ({"kind": "bfgs", "penalty": 0.0}, "driver.penalty", "a finite number in"),
    ],
)
def test_driver_keys_and_values_are_refused_by_name(tmp_path, driver, field, needle):
    """A key the driver does not take, or a value it cannot use, is refused naming the
    file, the field and what was expected (before: silently ignored, or run)."""
    body = "\n".join(f"{k} = {v!r}" for k, v in driver.items())
    path = tmp_path / "p.toml"
    path.write_text(
        "[problem]\nname='t'\nobjective='quad'\n[variables.x]\nunits='m'\nstart=0.1\n"
        f"lower=-1.0\nupper=1.0\n[driver]\n{body.replace(chr(39), chr(34))}\n"
    )
    with pytest.raises(EncdesignInputError, match=needle) as info:
        load_problem(path, REGISTRY)
    assert str(path) in str(info.value) and field in str(info.value)
    assert "expected" in str(info.value)


def test_sweep_table_takes_only_a_design_of_experiments():
    p = parse_problem(_problem(sweep={"kind": "lhs", "n": 9}), REGISTRY)
    assert p.sweep == LatinHypercube(n=9) and isinstance(
        parse_problem(_problem(), REGISTRY).sweep, Grid
    )
    with pytest.raises(EncdesignInputError, match=r"sweep\.kind.*unknown driver 'bfgs'"):
        parse_problem(_problem(sweep={"kind": "bfgs"}), REGISTRY)


def test_at_bound_is_ok_and_exits_zero(tmp_path, capsys):
    """An optimum on a bound is an answer, marked: ``result.ok`` and the CLI's exit code
    agree (exit 0), and the status says ``at_bound``. (The toy solve has the step cap of
    :func:`test_bound_hits_are_reported_in_optimize_and_sweep_json`'s: one compiled program.)"""
    d = _problem()
    d["variables"]["x"] = {"units": "m", "start": 0.0, "lower": -1.0, "upper": 0.2}
    r = solve_problem(parse_problem(d, REGISTRY))
    assert r.status is DriverStatus.AT_BOUND and r.ok, r.message
    assert r.best is not None and r.best.inputs["x"] == pytest.approx(0.2)
    assert r.summary()["driver"] == {
        "kind": "lbfgsb",
        "gtol": 1e-7,
        "max_steps": 200,
        "penalty": 1e4,
    }
    path = tmp_path / "p.toml"  # the CLI on a registered objective, optimum outside the box
    path.write_text(
        "[problem]\nname='sens'\nobjective='cotangent_sensitivity'\n"
        "[model]\nn_heads=3\nmax_order=9\nn_builds=0\n"
        "[variables.reference_angle]\nunits='deg'\nstart=6.0\nlower=5.0\nupper=7.0\n"
        "[driver]\nkind='lbfgsb'\n"
    )
    rc = main(["optimize", str(path), "--quiet", "--fresh-replicates", "0"])
    out = capsys.readouterr().out
    assert "at_bound" in out
    assert rc == 0


@pytest.mark.parametrize("cls", [BFGS, LevenbergMarquardt], ids=lambda c: c.__name__)
def test_solve_uses_the_drivers_defaults(cls):
    """The problem solve runs the driver object as given: one set of defaults."""
    p = parse_problem(_problem(driver={"kind": cls.kind}), REGISTRY)
    assert p.driver == cls()
    assert solve_problem(p).ok


def test_problem_result_renders_in_a_notebook():
    """``ProblemResult._repr_html_``: status, best design and every combination, escaped."""
    vars_ = _problem()["variables"] | {"k": {"values": [0, 1]}}
    data = _problem(variables=vars_, driver={"kind": "bfgs"})
    data["problem"] = dict(data["problem"], name="<b>bowl</b> & co")
    r = solve_problem(parse_problem(data, REGISTRY))
    h = r._repr_html_()
    assert "Problem &lt;b&gt;bowl&lt;/b&gt; &amp; co" in h and "<b>bowl</b>" not in h
    assert '<span class="badge ok">success</span>' in h and "minimize quad" in h
    assert f"<td>{r.best.objective:.8g}</td>" in h
    for name in ("x", "y"):
        assert f"<td>{name}</td><td>{r.best.inputs[name]:.6g}</td>" in h
    assert f"<td>f</td><td>{r.best.outputs['f']:.6g}</td>" in h
    assert h.count('class="badge ok"') == 1 + len(r.results)  # the result and each row
    assert "<td>best discrete</td><td>k = 0</td>" in h and "<td>k = 1</td>" in h
