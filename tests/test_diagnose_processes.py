"""``encdesign diagnose --processes`` / ``--coordinator``: one recording split over processes.

The fit's row passes (normal equations, column statistics; a selection round's trial fits
side by side, the rules' and the runs' alignment's row sums, the vibration start's line
search) are summed in fixed groups of chunks, each process its share, the groups' sums
gathered through ``jax.distributed``; the views and the detection bounds' probes are dealt
over the processes (``engine._workshare``), each process working on its share alone, the
results gathered: the diagnosis on two processes must equal the one on one process
(verdict, effects and every number within 1e-12 relative; timings aside), and each process
must have had a share of the dealt items and of every row pass's groups."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from encdesign import _distributed as dist
from encdesign import write_recording
from encdesign.io._parquet import write_parquet_table

CHUNK = 512
"""Rows per chunk in the spawned diagnoses (the engine's default is 8192): several groups
of chunks, so each process has a share of a 4 x 4000-row record."""

LAUNCH = (
    "import sys, encdesign.diagnose.engine._fit as f; f.CHUNK_ROWS = {chunk}; {setup}"
    "from encdesign.cli import main; sys.exit(main())"
)

REDUCE_SETTINGS = dict(reduce_min_rows=1000, reduce_attenuation_max=0.02, reduce_line_hz=10.0)
REDUCE_GATHER_ROWS = 700
REDUCE = (
    "import encdesign.diagnose._dispatch as d, encdesign.diagnose.engine._settings as s; "
    f"d.DEFAULT_SETTINGS = s.FinderSettings(**{REDUCE_SETTINGS!r}); "
    "import encdesign.diagnose.engine._engine as e; e.DEFAULT_SETTINGS = d.DEFAULT_SETTINGS; "
    f"import encdesign._distributed as g; g.GATHER_ROWS = {REDUCE_GATHER_ROWS}; "
)
"""Launcher setup that lowers the reduction's threshold and widens its bound, so that a
12,000-row record at 1 kHz (1,000-2,500 rows per revolution) is reduced to blocks of a few
rows as it is read (``open_recording``), and gathers the reduced rows 700 at a time (several
collectives per column, as at 10^8 rows); the engine's settings are the same (a restart,
``_reduce_restart``, reduces the record again with them)."""

DEALT = (
    "import jax, encdesign.diagnose.engine._workshare as w; "
    "w.shares = lambda ws, n, _s=w.shares: (lambda r: (open({log!r}, 'a').write("
    "f'{{jax.process_index()}} {{len(ws)}} {{len(r[jax.process_index()])}}\\n'), r)[1])"
    "(_s(ws, n)); "
)
"""Launcher setup that logs each dealing of work items (``_workshare.shares``): the process,
the items and its share, one line each to the file ``log``."""

SPLIT = (
    "import jax, encdesign.diagnose.engine._rowshare as rs; "
    "rs.allgather_rows = lambda rows, n, _g=rs.allgather_rows: (open({log!r}, 'a').write("
    "f'{{jax.process_index()}} {{n}} {{len(rows)}}\\n'), _g(rows, n))[1]; "
)
"""Launcher setup that logs each gather of a pass's row groups (``_rowshare.reduce_groups``
on several processes): the process, the groups and how many it summed, one line each to
the file ``log``."""

TIMING_KEYS = ("timings_s", "timings_cpu_s")


def _record(
    path: Path,
    seed: int,
    n: int = 1000,
    speed_rev_s: float = 0.6,
    group_rows: int = 0,
    orders: tuple[int, ...] = (1, 2, 3, 4, 5),
) -> Path:
    """4 heads x 4 runs of ``n`` rows (1 kHz, ``speed_rev_s`` + 0.4 r rev/s in run ``r``,
    0.5 urad noise, disk errors of ``orders`` (4 / m urad; 1.5 urad from order 13), per-run
    zeros) with a 31 Hz vibration of 1.5 urad on every head; with ``group_rows`` a Parquet
    table in row groups of that many rows (else a CSV)."""
    rng = np.random.default_rng(seed)
    amp = {m: 4e-6 / m if m < 13 else 1.5e-6 for m in orders}
    R, heads = 4, 4
    alpha = np.array([0.0, 2.1, 4.2, 0.9])
    cols: dict[str, list] = {"t": [], "run": [], "theta_ref": []} | {
        f"h{k}": [] for k in range(heads)
    }
    for r in range(R):
        t = np.arange(n) / 1000.0
        th = 2 * np.pi * (speed_rev_s + 0.4 * r) * t + rng.uniform(0, 6)
        zero = rng.uniform(-3, 3, heads)
        cols["t"].append(t)
        cols["run"].append(np.full(n, r))
        cols["theta_ref"].append(th + rng.uniform(-3, 3))
        for k in range(heads):
            e = sum(a * np.sin(m * (th - alpha[k]) + m) for m, a in amp.items())
            e = e + 1.5e-6 * np.sin(2 * np.pi * 31.0 * t + rng.uniform(0, 6))
            cols[f"h{k}"].append(th + e + rng.normal(0, 0.5e-6, n) + zero[k])
    columns = {k: np.concatenate(v) for k, v in cols.items()}
    enc = {
        "optical_radius_m": 0.0254,
        "head_angles_deg": np.degrees(alpha).tolist(),
        "signal_periods_per_rev": 2048,
    }
    back = write_recording(path, "multihead", columns, encoder=enc, parquet=group_rows > 0)
    if group_rows:
        with open(path.parent / back.meta["data"], "wb") as fh:
            write_parquet_table(fh, columns, row_group_rows=group_rows)
    return path


def _env() -> dict[str, str]:
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


def _diagnose(rec: Path, out: Path, processes: int, port: int, setup: str = "", *flags) -> dict:
    """Run the diagnosis on ``processes`` processes joined by the ``--coordinator`` flags
    (the launcher sets the small chunk size and runs ``setup`` first) and return process 0's
    JSON."""
    code = LAUNCH.format(chunk=CHUNK, setup=setup)
    base = [sys.executable, "-c", code, "diagnose", str(rec), *flags]
    base += ["--json", str(out), "--quiet"]
    if processes == 1:
        cmds = [base]
    else:
        cmds = [
            [
                *base,
                "--coordinator",
                f"localhost:{port}",
                "--num-processes",
                str(processes),
                "--process-id",
                str(i),
            ]
            for i in range(processes)
        ]
    procs = [
        subprocess.Popen(c, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for c in cmds
    ]
    outs = [p.communicate(timeout=240) for p in procs]
    for p, (so, se) in zip(procs, outs):
        assert p.returncode == 0, f"status {p.returncode}\n{so[-2000:]}\n{se[-4000:]}"
    return json.loads(out.read_text(encoding="utf-8"))


def _diagnose_here(monkeypatch, rec: Path, out: Path, reduce: bool = False, *flags) -> dict:
    """The one-process diagnosis in this test process: ``main`` as the launcher calls it, with
    its chunk size and, with ``reduce``, :data:`REDUCE`'s settings (patched for this test
    only; no interpreter to start: CI time). Returns its JSON."""
    import encdesign._distributed as g
    import encdesign.diagnose._dispatch as d
    import encdesign.diagnose.engine._engine as e
    import encdesign.diagnose.engine._fit as f
    from encdesign.cli import main
    from encdesign.diagnose.engine._settings import FinderSettings

    monkeypatch.setattr(f, "CHUNK_ROWS", CHUNK)
    if reduce:
        monkeypatch.setattr(d, "DEFAULT_SETTINGS", FinderSettings(**REDUCE_SETTINGS))
        monkeypatch.setattr(e, "DEFAULT_SETTINGS", d.DEFAULT_SETTINGS)
        monkeypatch.setattr(g, "GATHER_ROWS", REDUCE_GATHER_ROWS)
    assert main(["diagnose", str(rec), *flags, "--json", str(out), "--quiet"]) == 0
    return json.loads(out.read_text(encoding="utf-8"))


def _differences(a, b, where: str = "") -> list[str]:
    """Where the documents differ: strings, booleans and integers exactly, floats beyond
    1e-12 relative; timings (wall and CPU seconds, the report's status line) are not
    compared."""
    if isinstance(a, dict):
        if not isinstance(b, dict) or set(a) != set(b):
            return [f"{where}: keys differ"]
        return [
            d
            for k in a
            if k not in TIMING_KEYS and not k.endswith("time_s")
            for d in _differences(a[k], b[k], f"{where}.{k}")
        ]
    if isinstance(a, list):
        if not isinstance(b, list) or len(a) != len(b):
            return [f"{where}: lengths differ"]
        return [
            d for i, (x, y) in enumerate(zip(a, b)) for d in _differences(x, y, f"{where}[{i}]")
        ]
    if isinstance(a, str) and isinstance(b, str) and where == ".report":
        a, b = (re.sub(r"status: (.*); [0-9.]+ s", r"status: \1", s) for s in (a, b))
    if isinstance(a, float) and isinstance(b, float):
        same = (np.isnan(a) and np.isnan(b)) or abs(a - b) <= 1e-12 * abs(a)
        return [] if same else [f"{where}: {a!r} vs {b!r}"]
    return [] if a == b and type(a) is type(b) else [f"{where}: {a!r} vs {b!r}"]


def _keep(one: dict, two: dict) -> None:
    if os.environ.get("ENCDESIGN_KEEP"):
        Path(os.environ["ENCDESIGN_KEEP"]).mkdir(exist_ok=True)
        for name, doc in (("one", one), ("two", two)):
            Path(os.environ["ENCDESIGN_KEEP"], name + ".json").write_text(json.dumps(doc))


def _dealt(log: Path) -> dict[int, list[tuple[int, int]]]:
    """Per process, ``(items, its share)`` of each dealing logged by :data:`DEALT`."""
    out: dict[int, list[tuple[int, int]]] = {}
    for line in log.read_text(encoding="utf-8").splitlines():
        p, n, k = (int(v) for v in line.split())
        out.setdefault(p, []).append((n, k))
    return out


def _assert_shared(split: Path, log: Path, two: dict) -> None:
    """What :data:`SPLIT` and :data:`DEALT` logged on two processes: every row pass, the
    trial fits' (side by side, their starts dealt) and the row sums of the rules and the
    runs' alignment among them, split (the same gathers on both processes, each having
    summed its share of the groups); the views and the bounds' probes dealt (the same
    dealings on both processes, their shares adding up, each with work in all of them)."""
    assert dist.process_count() == 1  # this test process joined nothing
    rows = _dealt(split)
    assert sorted(rows) == [0, 1] and [n for n, _ in rows[0]] == [n for n, _ in rows[1]]
    assert len(rows[0]) >= 20
    for (n, k0), (_, k1) in zip(rows[0], rows[1]):
        assert k0 + k1 == n and k0 >= 1 and (k1 >= 1 or n < 2)
    dealt = _dealt(log)
    assert sorted(dealt) == [0, 1] and [n for n, _ in dealt[0]] == [n for n, _ in dealt[1]]
    assert len(dealt[0]) >= 2  # the views of each residual and the bounds' probes
    for (n, k0), (_, k1) in zip(dealt[0], dealt[1]):
        assert k0 + k1 == n and (k0 >= 1 and k1 >= 1 or n < 2)
    assert len(two["detection_bounds"]) >= 2


@pytest.mark.sweep  # CI time (session 33): make test makes these checks on the restart test
def test_two_processes_give_the_one_process_diagnosis(tmp_path, monkeypatch):
    """A CSV record never reduced, on two processes: its row passes split and its views and
    probes dealt (:func:`_assert_shared`), and the one-process diagnosis. In ``make test``
    the restart test below makes the same checks on its whole record, which after the
    restart is never reduced either (a Parquet file every process reads whole, as it
    reads a CSV): this one runs in ``make test-sweeps``."""
    rec = _record(tmp_path / "rec.toml", seed=20261204)
    log, split = tmp_path / "dealt.txt", tmp_path / "split.txt"
    one = _diagnose_here(monkeypatch, rec, tmp_path / "one.json")
    setup = DEALT.format(log=str(log)) + SPLIT.format(log=str(split))
    two = _diagnose(rec, tmp_path / "two.json", 2, dist.free_port(), setup)
    _assert_shared(split, log, two)
    assert one["verdict"] == two["verdict"]
    assert [e["name"] for e in one["effects"]] == [e["name"] for e in two["effects"]]
    assert one["effects"], "the vibration is named"
    diff = _differences(one, two)
    _keep(one, two)
    assert not diff, "\n".join(diff[:40])


def test_a_parquet_record_reduced_on_two_processes_gives_the_one_process_diagnosis(
    tmp_path, monkeypatch
):
    """A Parquet record reduced as it is read, each process reading its share of the row
    groups (997 rows each: the shares meet at row 6,979, inside a block), gives the one-process
    diagnosis: the same reduced rows (counts in ``reduced``), verdict and numbers."""
    rec = _record(tmp_path / "rec.toml", 4703, n=3000, speed_rev_s=0.4, group_rows=997)
    flags = ("--max-order", "6")
    one = _diagnose_here(monkeypatch, rec, tmp_path / "one.json", True, *flags)
    two = _diagnose(rec, tmp_path / "two.json", 2, dist.free_port(), REDUCE, *flags)
    red = one["reduced"]
    assert red["applied"] and red["streamed_row_groups"] == 13 and red["block_rows"] >= 3
    assert red["stretches"] == 4  # the runs
    blocks = 12_000 // red["block_rows"]
    assert blocks - red["stretches"] <= red["reduced_rows"] <= blocks
    assert one["verdict"] == two["verdict"] == "missing_physics"
    assert [e["name"] for e in one["effects"]] == [e["name"] for e in two["effects"]]
    diff = _differences(one, two)
    _keep(one, two)
    assert not diff, "\n".join(diff[:40])


def test_a_reduced_record_restarted_on_two_processes_gives_the_one_process_diagnosis(
    tmp_path, monkeypatch
):
    """Disk orders 13-18 grow the base past what the block planned for order 12 keeps
    (``_reduce_restart``): every process stops at the same growth and reads the record
    again (the block for every growth is under 2 rows there: the whole record), and the
    diagnosis on two processes is the one on one process. Its row passes are split and its
    views and probes dealt (:func:`_assert_shared`: the two-process checks of the CSV test
    above, which runs in ``make test-sweeps`` only; CI time, session 33)."""
    orders = (1, 2, 3, 4, 5, *range(13, 19))
    rec = _record(
        tmp_path / "rec.toml", 7972, n=3000, speed_rev_s=0.4, group_rows=997, orders=orders
    )
    log, split = tmp_path / "dealt.txt", tmp_path / "split.txt"
    one = _diagnose_here(monkeypatch, rec, tmp_path / "one.json", True)
    setup = REDUCE + DEALT.format(log=str(log)) + SPLIT.format(log=str(split))
    two = _diagnose(rec, tmp_path / "two.json", 2, dist.free_port(), setup)
    _assert_shared(split, log, two)
    red = one["reduced"]
    assert not red["applied"] and red["planned_for_growth"]
    assert red["restart"]["block_rows"] >= 2 and one["base"]["max_order"] > 12
    assert one["verdict"] == two["verdict"]
    assert [e["name"] for e in one["effects"]] == [e["name"] for e in two["effects"]]
    diff = _differences(one, two)
    _keep(one, two)
    assert not diff, "\n".join(diff[:40])


def test_shares_deal_every_item_once_the_heaviest_first():
    """The dealing (``_workshare.shares``) gives each item to one process, the heaviest first
    to the least loaded: loads differ by at most the heaviest item."""
    from encdesign.diagnose.engine._workshare import shares

    rng = np.random.default_rng(5100)
    for n in (1, 2, 3):
        for m in (0, 1, 5, 17):
            w = rng.uniform(1, 4, m).tolist()
            got = shares(w, n)
            assert len(got) == n and sorted(i for s in got for i in s) == list(range(m))
            loads = [sum(w[i] for i in s) for s in got]
            assert max(loads) - min(loads) <= max(w, default=0.0)
    assert shares([1.0] * 5, 2) == [[0, 2, 4], [1, 3]]


def test_items_summed_in_groups_equal_their_sum():
    """``_rowshare.summed_items`` (the runs' alignment sums, split over the processes by
    blocks of rows) gives the sum of the items on one process, whatever their number, and
    the same inside a share of dealt items (``alone``)."""
    from encdesign.diagnose.engine._rowshare import alone, summed_items

    rng = np.random.default_rng(5102)
    for n in (0, 1, 3, 16, 17, 40):
        x = rng.normal(size=(n, 3, 2))

        def add(sums, i, x=x):
            sums[0] += x[i]
            sums[1][i % 2] += 1.0

        got = summed_items(n, [np.zeros((3, 2)), np.zeros(2)], add)
        assert np.allclose(got[0], x.sum(0), rtol=1e-13, atol=1e-13)
        assert got[1].tolist() == [float((n + 1) // 2), float(n // 2)]
        with alone():
            again = summed_items(n, [np.zeros((3, 2)), np.zeros(2)], add)
        assert all(np.array_equal(a, b) for a, b in zip(got, again))


def test_gains_of_a_tall_skinny_qr_over_groups_equal_one_qr():
    """``_runout.split_gains`` (the vibration start's line search, rows split over the
    processes): the groups' QRs, factored again, give the gain of one QR of the whole
    design, also where a group holds rows of one run only (its design rank deficient)."""
    import encdesign.diagnose.kinds.multihead._runout as ro

    rng = np.random.default_rng(7530)
    n = 40_000
    t = np.sort(rng.uniform(0, 10, n))
    oh = np.zeros((n, 4))
    oh[np.arange(n), (t // 2.5).astype(int)] = 1.0
    rw = rng.normal(size=(n, 4)) + np.sin(2 * np.pi * 3.1 * t)[:, None]
    fs = 3.1 + np.linspace(-0.2, 0.2, 5)

    def sets(a, b):
        ph = [2 * np.pi * f * t[a:b] for f in fs]
        return [
            np.concatenate([np.cos(p)[:, None] * oh[a:b], np.sin(p)[:, None] * oh[a:b]], 1)
            for p in ph
        ]

    old = ro.SPLIT_ROWS
    ro.SPLIT_ROWS = 1000  # 40 blocks in 16 groups, most of one run
    try:
        got = ro.split_gains(n, sets, rw)
    finally:
        ro.SPLIT_ROWS = old
    want = [ro._gain(rw, X) for X in sets(0, n)]
    assert np.allclose(got, want, rtol=1e-13, atol=0.0)
    assert ro.split_gains(3, sets, rw[:3]) == [0.0] * 5  # fewer rows than columns


def test_a_trial_fit_is_gathered_whole_and_rejoins_its_candidates():
    """A fit travels without its candidates (``pack_fit``: they hold functions) and comes
    back with this process's candidate objects, every number as it was; another candidate
    list is refused; on one process ``deal`` is the work itself."""
    import pickle
    from types import SimpleNamespace

    from encdesign.diagnose.engine._dealt_fits import pack_fit, unpack_fit
    from encdesign.diagnose.engine._fit import FitResult, Term
    from encdesign.diagnose.engine._workshare import deal

    a, b = SimpleNamespace(name="a"), SimpleNamespace(name="b")
    rng = np.random.default_rng(5101)
    terms = [
        Term(c, {"x": rng.normal(size=3)}, {"x": np.ones(3, bool)}, {"x": np.ones(3)})  # type: ignore[arg-type]
        for c in (a, b)
    ]
    A = rng.normal(size=(6, 6))
    fr = FitResult(terms, 1.25, 6, A @ A.T, 2.5, 0.1, 0.05, 400, True, A, [], [(0, 3), (3, 6)])
    back = unpack_fit(pickle.loads(pickle.dumps(pack_fit(fr))), [a, b])  # type: ignore[list-item]
    assert back is not None and [t.cand for t in back.terms] == [a, b]
    assert np.array_equal(back.terms[1].values["x"], fr.terms[1].values["x"])
    assert np.array_equal(back.cov, fr.cov) and back.chi2 == fr.chi2
    assert fr.terms[0].cand is a  # the original is untouched
    with pytest.raises(ValueError, match="terms"):
        unpack_fit(pack_fit(fr), [b, a])  # type: ignore[list-item]
    assert pack_fit(None) is None and unpack_fit(None, []) is None
    assert deal([3, 1, 2], lambda xs: [x * x for x in xs]) == [9, 1, 4]


def test_a_private_fitter_caches_apart_from_the_shared_one():
    """What a trial fit caches on its own fitter (``_dealt_fits.private``) never reaches the
    shared fitter's caches: each process's shared fitter stays as the others' are."""
    from types import SimpleNamespace

    from encdesign.diagnose.engine._dealt_fits import private
    from encdesign.diagnose.engine._fit import Fitter

    prep = SimpleNamespace(sigma=np.ones(2), n=100)
    shared = Fitter(prep)  # type: ignore[arg-type]
    shared.blocks.keep_gram(("a",), np.eye(2), np.eye(2))
    own = private(shared)
    own.blocks.keep_gram(("b",), np.eye(2), np.eye(2))
    own._jcache["x"] = 1
    assert own.blocks.gram(("a",)) is not None and own.blocks.gram(("b",)) is not None
    assert shared.blocks.gram(("b",)) is None and "x" not in shared._jcache
