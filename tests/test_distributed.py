"""Scale-out on jax.distributed + jax.sharding: launch flags, sharded builds, processes.

The agreement checks (``tests/distributed_worker.py``) run a Monte Carlo yield and the traced
builds path in this process on one CPU device (the reference), in one process with 4 CPU
devices (``--xla_force_host_platform_device_count``) and as 2 processes on localhost (gloo
collectives): one spawn each, started together with the reference so the three compile at
once, and compared at 1e-12 relative.
"""

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import env_without_device_count

from encdesign import EncdesignInputError, _kv_gather
from encdesign import _distributed as dist
from encdesign.cli import main
from encdesign.design._cases import CaseRecorder, part_path, read_cases

WORKER = Path(__file__).resolve().parent / "distributed_worker.py"
RTOL = 1e-12


def _env(**extra: str) -> dict:
    return env_without_device_count(**extra)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The reference (here, one device), 4 devices in one process, and 2 processes."""
    import distributed_worker
    import jax
    from jax.sharding import Mesh

    d = tmp_path_factory.mktemp("runs")
    four = subprocess.Popen(
        [sys.executable, str(WORKER), str(d / "four.json"), "--sds"],
        env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=4"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    two: dict = {}

    def spawn_two() -> None:
        prog = [sys.executable, str(WORKER)]
        two["rc"] = dist.spawn_local([str(d / "two.json")], 2, env=_env(), program=prog)

    thread = threading.Thread(target=spawn_two)
    thread.start()
    try:
        with jax.set_mesh(Mesh(np.array(jax.devices()[:1]), (dist.BUILDS_AXIS,))):
            single = distributed_worker.run_checks(sds=True)
    finally:
        thread.join(600)
        log = four.communicate(timeout=600)[0].decode("utf-8", "replace")
    assert four.returncode == 0, log[-4000:]
    assert two.get("rc") == 0
    assert single["devices"] == 1 and single["processes"] == 1
    return {
        "single": single,
        "four": json.loads((d / "four.json").read_text()),
        "two": json.loads((d / "two.json").read_text()),
    }


def _agree(a: dict, b: dict) -> None:
    va, vb = np.asarray(a["values"]), np.asarray(b["values"])
    assert va.shape == vb.shape == (len(a["values"]),)
    np.testing.assert_allclose(vb, va, rtol=RTOL, atol=0)
    assert b["mean"] == pytest.approx(a["mean"], rel=RTOL, abs=0)
    assert b["yield"] == a["yield"] and b["spec"] == pytest.approx(a["spec"], rel=RTOL)
    assert 0.3 < a["yield"] < 0.7  # the median as the spec: about half the builds pass
    np.testing.assert_allclose(b["grad"], a["grad"], rtol=RTOL, atol=0)
    assert np.all(np.abs(a["grad"]) > 0)
    assert b["again"] == pytest.approx(a["again"], rel=RTOL, abs=0)
    assert b["mean_mesh_input"] == pytest.approx(a["mean"], rel=RTOL, abs=0)
    if "sds" in b:
        np.testing.assert_allclose(b["sds"], a["sds"], rtol=RTOL, atol=0)
        assert len(set(a["sds"])) == len(a["sds"])  # distinct builds, not one repeated


def test_four_cpu_devices_agree_with_one(runs):
    r = runs["four"]
    assert r["devices"] == 4 and r["processes"] == 1 and "sds" in r
    _agree(runs["single"], r)


def test_two_processes_on_localhost_agree_with_one(runs):
    r = runs["two"]
    assert r["devices"] == 2 and r["processes"] == 2
    _agree(runs["single"], r)
    # tasks (e.g. benchmark recordings) dealt round-robin and gathered
    assert r["tasks"] == [{"task": i, "by": i % 2} for i in range(5)]
    assert runs["single"]["tasks"] == [{"task": i, "by": 0} for i in range(5)]
    # gathers of every size: small ones through the key-value store, exact (nothing compiled)
    g, m = r["gathers"], (_kv_gather.CHUNK_BYTES + 3 * _kv_gather.KV_BYTES_MAX) // 8
    assert g["rows"] == [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0], [10.0, 11.0, 12.0], [13.0, 14.0, 15.0]]
    assert g["bytes"] == ["p0", "p1p1"]
    assert g["big_size"] == 2 * m + 5  # over KV_BYTES_MAX: two pieces through one program
    assert g["big_sum"] == m * (m - 1) // 2 + (m + 5) * (m + 4) // 2 + 7 * (m + 5)
    assert (g["through_store"], g["compiled"]) == (2, 1)
    assert runs["single"]["gathers"]["rows"] == g["rows"][:2]


def test_processes_out_of_step_in_a_gather_raise_a_clear_error(tmp_path):
    """Process 0 gathers rows while process 1 gathers bytes: both raise a DistributedError
    that names both gathers, within seconds (no hang)."""
    t0 = time.monotonic()
    out = tmp_path / "m.json"
    rc = dist.spawn_local(
        [str(out), "--mismatch"], 2, env=_env(), program=[sys.executable, str(WORKER)]
    )
    assert rc == 0 and time.monotonic() - t0 < 120
    for k in (0, 1):
        msg = Path(f"{out}.p{k}").read_text()
        assert msg.startswith("DistributedError: gather 0: process")
        assert "'rows'" in msg and "'bytes'" in msg and "out of step" in msg


class _Store:
    """An in-memory key-value store with the runtime client's methods (threads as processes)."""

    def __init__(self) -> None:
        self.kv: dict[str, bytes] = {}
        self.cv = threading.Condition()
        self.most = 0

    def key_value_set_bytes(self, key: str, value: bytes, allow_overwrite: bool = False) -> None:
        with self.cv:
            assert allow_overwrite or key not in self.kv
            self.kv[key] = bytes(value)
            self.most = max(self.most, len(self.kv))
            self.cv.notify_all()

    def blocking_key_value_get_bytes(self, key: str, timeout_in_ms: int) -> bytes:
        with self.cv:
            if not self.cv.wait_for(lambda: key in self.kv, timeout_in_ms / 1000):
                raise RuntimeError(f"DEADLINE_EXCEEDED: {key}")
            return self.kv[key]

    def key_value_delete(self, key: str) -> None:
        with self.cv:  # a key, or a folder ("…/") and every key in it
            for k in [k for k in self.kv if k == key or (key.endswith("/") and k.startswith(key))]:
                del self.kv[k]


def _on_threads(n: int, work, monkeypatch=None) -> list:
    """``work(gatherer, k)`` on ``n`` threads as processes ``k``, sharing a :class:`_Store`
    (with ``monkeypatch``, the compiled all-gather too: a collective of the threads)."""
    store, out = _Store(), [None] * n
    if monkeypatch is not None:
        meet, parts = threading.Barrier(n), {}

        def compiled(x):
            parts[threading.current_thread().name] = np.array(x)
            meet.wait(10)
            got = np.stack([parts[f"p{p}"] for p in range(n)])
            meet.wait(10)
            return got

        monkeypatch.setattr(_kv_gather, "compiled_allgather", compiled)

    def run(k: int) -> None:
        g = _kv_gather.StoreGather(
            store, k, n, max_bytes=4096, chunk_bytes=1000, whole_bytes=20000, timeout_ms=2000
        )
        try:
            out[k] = work(g, k)
        except Exception as exc:
            out[k] = exc

    threads = [threading.Thread(target=run, args=(k,), name=f"p{k}") for k in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    return [store, *out]


def test_store_gathers_are_exact_and_the_store_does_not_grow(monkeypatch):
    rng = np.random.default_rng(5)
    parts = [rng.standard_normal((40, 7)) * 10.0 ** rng.integers(-300, 300, (40, 7)) for _ in "abc"]

    def work(g, k):
        got = []
        for i in range(50):  # 105 gathers: the store holds their keys a folder at a time
            got.append(g.allgather(parts[k][: 4 + i % 40] * (i + 1), "sums"))
            got.append(g.allgather_bytes(b"%d:" % k * (k + 1) * (50 * i), "blobs"))
            if i % 10 == 0:  # over whole_bytes: one compiled gather of its own shape
                got.append(g.allgather(np.arange(3000) * (k + i), "whole"))
        return got, g.through_store, g.compiled

    store, *res = _on_threads(3, work, monkeypatch)
    for got, n_store, n_compiled in res:
        # small ones through the store, the larger in pieces of 1000 bytes (one compiled shape)
        assert (n_store, n_compiled) == (64, 41)  # a blob over 4096 bytes from i = 14
        for i in range(50):
            want = np.stack([p[: 4 + i % 40] * (i + 1) for p in parts])
            assert got.pop(0).tobytes() == want.tobytes()  # bit for bit
            assert got.pop(0) == [b"%d:" % p * (p + 1) * (50 * i) for p in range(3)]
            if i % 10 == 0:
                assert np.array_equal(got.pop(0), [np.arange(3000) * (p + i) for p in range(3)])
    assert store.most <= 3 * (_kv_gather.KEYS_PER_FOLDER + 2)
    assert len(store.kv) == 3 * (105 % _kv_gather.KEYS_PER_FOLDER)


def test_a_store_gather_out_of_step_raises_and_names_both():
    def work(g, k):
        g.allgather_bytes(b"ok", "first")
        if k == 0:
            return g.allgather(np.zeros(3), "sums")
        return g.allgather(np.zeros(4), "sums")

    _, a, b = _on_threads(2, work)
    for exc in (a, b):
        assert isinstance(exc, dist.DistributedError)
        assert "gather 1" in str(exc) and "<f8[3]" in str(exc) and "<f8[4]" in str(exc)


def test_chunk_plan_spreads_the_builds_evenly():
    assert dist.chunk_plan(100_000, 2048, 1, 8) == (2048, 49)
    assert dist.chunk_plan(100_000, 2048, 2, 8) == (2000, 25)  # was 2 x 25 x 2048
    assert dist.chunk_plan(100_000, 2048, 4, 8) == (1928, 13)
    assert dist.chunk_plan(203, 32, 4, 8) == (32, 2)
    assert dist.chunk_plan(3, 5, 4, 8) == (1, 1)
    for n, cap, shards in [(1, 1, 1), (999, 64, 3), (4096, 4096, 2), (10**6, 4096, 7)]:
        block, chunks = dist.chunk_plan(n, cap, shards, 8)
        assert block <= cap and block * chunks * shards >= n
        assert (block - 8) * chunks * shards < n  # no more than 8 builds padding per block


def test_collectives_are_padded_to_few_shapes():
    """A collective of ``n`` values is padded to ``bucket(n)``: at least ``n``, at most half
    as much again, and only two lengths per power of two (each compiled once)."""
    got = [dist.bucket(n) for n in range(1, 5000)]
    assert all(n <= b <= max(1, 3 * n // 2) for n, b in zip(range(1, 5000), got))
    assert len(set(got)) <= 2 * 13
    assert [dist.bucket(n) for n in (0, 1, 2, 3, 5, 7, 1024, 1025, 1537)] == [
        1,
        1,
        2,
        3,
        6,
        8,
        1024,
        1536,
        2048,
    ]


def test_a_dead_process_stops_the_run_in_bounded_time(tmp_path, capsys):
    t0 = time.monotonic()
    rc = dist.spawn_local(
        [str(tmp_path / "x.json"), "--die"], 2, program=[sys.executable, str(WORKER)]
    )
    elapsed = time.monotonic() - t0
    assert rc == 1 and not (tmp_path / "x.json").exists()
    assert "process 1 of 2 failed (status 7)" in capsys.readouterr().err
    assert elapsed < 120  # the survivor is stopped at once, not after a heartbeat timeout


def test_unreachable_coordinator_is_a_clear_error_in_bounded_time():
    port = dist.free_port()
    launch = dist.check_launch(None, f"127.0.0.1:{port}", 2, 1)
    t0 = time.monotonic()
    with pytest.raises(dist.DistributedError, match="not reachable within 1 s"):
        dist.initialize(launch, timeout_s=1.0)
    assert time.monotonic() - t0 < 10


@pytest.mark.parametrize(
    "text, host, port",
    [("localhost:1234", "localhost", 1234), ("10.0.0.7:80", "10.0.0.7", 80), ("[::1]:9", "::1", 9)],
)
def test_coordinator_addresses_parse(text, host, port):
    assert dist.parse_coordinator(text) == (host, port)


@pytest.mark.parametrize(
    "flags, where",
    [
        (["--processes", "0"], "--processes"),
        (["--processes", "-3"], "--processes"),
        (["--coordinator", "localhost"], "--coordinator"),
        (["--coordinator", "host:port"], "--coordinator"),
        (["--coordinator", "localhost:70000"], "--coordinator"),
        (["--coordinator", "a b:12", "--num-processes", "2", "--process-id", "0"], "--coord"),
        (["--coordinator", "localhost:1234", "--num-processes", "2", "--process-id", "2"], "-id"),
        (["--coordinator", "localhost:1234", "--num-processes", "2", "--process-id", "-1"], "-id"),
        (["--coordinator", "localhost:1234", "--num-processes", "0", "--process-id", "0"], "-num"),
        (["--coordinator", "localhost:1234"], "--coordinator"),
        (["--num-processes", "2"], "--num-processes"),
    ],
)
@pytest.mark.parametrize("command", ["sweep", "optimize"])
def test_bad_launch_flags_exit_2(command, flags, where, capsys):
    rc = main([command, "examples/residual_3p1.toml", *flags])
    assert rc == 2
    err = capsys.readouterr().err
    assert where in err and "expected" in err


def test_launch_checks_raise_input_errors():
    with pytest.raises(EncdesignInputError, match="0…3"):
        dist.check_launch(None, "localhost:5", 4, 4)
    assert dist.check_launch(3).spawns and not dist.check_launch(3).distributed
    assert dist.check_launch(None, "auto").coordinator == "auto"


SWEEP_TOML = """
[problem]
name = "scale sweep"
objective = "residual"
seed = {seed}

[model]
radius_m = 0.0254
tilt_rad = 6e-3
n_heads = 3
max_order = 4
grating_orders = 4
n_angles = 32
n_builds = 40
chunk_size = 8
sigma_eccentricity = 5e-6
sigma_tilt = 1e-3
sigma_placement = 2e-4
sigma_grating = 5e-6

[variables.reference_angle]
units = "deg"
start = 20.0
lower = 14.0
upper = 28.0

[sweep]
kind = "grid"
points_per_dim = 9
chunk_size = 2
"""


# the resume and scale-out tests check the case files, not the fresh-build check of the
# answer (tests/test_validate.py): no fresh replicates (each one is a new evaluation)
NO_FRESH = ("--fresh-replicates", "0")
QUIET = ("--quiet", *NO_FRESH)


def _sweep_file(tmp_path: Path, seed: int = 1) -> Path:
    p = tmp_path / f"sweep{seed}.toml"
    p.write_text(SWEEP_TOML.format(seed=seed))
    return p


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep")
    cases = d / "full.jsonl"
    assert main(["sweep", str(_sweep_file(d)), "--cases", str(cases), *QUIET]) == 0
    return read_cases(cases)


@pytest.mark.parametrize("kept", [0, 4, 8])
def test_sweep_resume_gives_the_uninterrupted_table(uninterrupted, tmp_path, kept, capsys):
    """An interrupted case file (the first ``kept`` cases, or the last ones) is completed;
    the cases recorded are not evaluated again; the final file equals the full run's."""
    from encdesign.design._cases import write_cases

    part = tmp_path / "part.jsonl"
    write_cases(part, uninterrupted[:kept] if kept < 8 else uninterrupted[1:])
    assert main(["sweep", str(_sweep_file(tmp_path)), "--resume", str(part), *QUIET]) == 0
    assert read_cases(part) == uninterrupted
    reused = kept if kept < 8 else 8
    assert f"{reused} reused from the earlier run" in capsys.readouterr().out


def test_sweep_resume_checks_the_seed(uninterrupted, tmp_path, capsys):
    import dataclasses

    from encdesign.design._cases import write_cases

    # the first 5 cases as if run with seed 2, resumed by the seed-1 sweep (the seed-1
    # program is the fixture's: a sweep of another seed would compile its builds anew)
    part = tmp_path / "other-seed.jsonl"
    write_cases(part, [dataclasses.replace(c, seed=2) for c in uninterrupted[:5]])
    assert main(["sweep", str(_sweep_file(tmp_path)), "--resume", str(part), *NO_FRESH]) == 0
    out = read_cases(part)
    assert "0 reused" in capsys.readouterr().out
    assert [c.seed for c in out[:9]] == [1] * 9 and len(out) == 14  # seed-2 cases kept after
    assert [c.seed for c in out[9:]] == [2] * 5


def test_sweep_on_two_processes_writes_the_same_case_file(uninterrupted, tmp_path):
    cases = tmp_path / "two.jsonl"
    argv = [
        "sweep",
        str(_sweep_file(tmp_path)),
        "--cases",
        str(cases),
        "--processes",
        "2",
        *NO_FRESH,
    ]
    env = env_without_device_count()
    rc = dist.spawn_local(dist.strip_launch_flags(argv), 2, env=env)
    assert rc == 0
    got = read_cases(cases)
    assert [c.inputs for c in got] == [c.inputs for c in uninterrupted]
    for a, b in zip(got, uninterrupted):
        assert a.status == b.status and a.seed == b.seed
        for k in a.outputs:
            assert a.outputs[k] == pytest.approx(b.outputs[k], rel=RTOL, abs=0)
    assert not list(tmp_path.glob(".two.part-*"))  # shard files merged and removed


def test_interrupted_recorder_keeps_its_cases_and_shard(tmp_path):
    path = tmp_path / "c.jsonl"
    with pytest.raises(KeyboardInterrupt), CaseRecorder(path, process=1, write=True) as rec:
        rec.record({"x": 0.25}, {"f": 1.0}, "success", 3)
        rec.record_part([({"x": 0.5}, {"f": 2.0}, "success", 3)])
        raise KeyboardInterrupt
    assert [c.inputs for c in read_cases(path)] == [{"x": 0.25}]
    assert part_path(path, 1).exists()
    resumed = CaseRecorder(path, resume=True)
    assert resumed.lookup({"x": 0.5}, 3) is not None and resumed.lookup({"x": 0.5}, 4) is None
