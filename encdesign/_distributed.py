"""Scale-out on JAX's own distributed runtime: devices, processes and hosts.

encdesign does not run a task farm of its own. It uses

* :mod:`jax.sharding` — the builds axis of every Monte Carlo driver
  (:func:`~encdesign.design.map_builds` and everything built on it: ``monte_carlo``,
  ``expected_value``, ``build_metrics``, ``sds_residuals``, the tolerance sweeps and
  allocation) is split over a one-axis :class:`~jax.sharding.Mesh` named ``"builds"``
  (:func:`shard_builds`): one slice of builds per device, laid out on the mesh with
  :func:`jax.lax.with_sharding_constraint` and partitioned by XLA's SPMD partitioner (GSPMD;
  ``jax.shard_map`` was tried first, but a closed-over design that is itself an output on
  the mesh, as in every solver step, cannot enter its manual region). Every device
  evaluates a contiguous slice of builds, chunked as before (memory per device stays
  bounded), and the per-build values are gathered (an all-gather: 8 bytes per build) so
  that the reductions that follow (mean, percentile, yield) see the same array in the same
  order as one device. :func:`~encdesign.design.monte_carlo` (host inputs, so it can use
  ``jax.shard_map``) leaves each chunk's values on their devices and gathers them only at
  the end (:func:`gather_chunks`), so the processes never wait for each other mid-run.
  Build ``i`` depends only on ``fold_in(key, i)``, so the values are those of a
  single-device run; with one device nothing changes (no sharding at all).
* :func:`jax.distributed.initialize` — the multi-controller runtime. With it, the mesh
  spans the devices of all processes and every process runs the same program (SPMD); the
  all-gather crosses processes (gloo on CPU, NCCL on GPU). :func:`initialize` wraps it
  with checks: a coordinator address that does not parse, a process id outside
  ``0 … N-1`` or a process count below 1 are input errors; a coordinator that cannot be
  reached is a :class:`DistributedError` within ``timeout_s``; a process that dies is
  detected by the runtime's heartbeat (``heartbeat_s``) and the others stop.
* :func:`spawn_local` — ``--processes N`` on one machine: N copies of the same command
  with a coordinator on localhost (for tests and many-core boxes). A child that fails
  stops the others at once.

Which mesh is used: the one set with :func:`jax.set_mesh` when it has a ``"builds"``
axis (:func:`use_local_devices` sets one over this process's devices, for work that
each process does on its own, such as its share of sweep cases); otherwise all devices
of all processes (:func:`builds_mesh`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import ipaddress
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from . import _cpu
from ._checks import int_arg
from ._errors import DistributedError, EncdesignInputError, input_error
from ._kv_gather import StoreGather, bucket, compiled_allgather, padded_bytes_allgather

BUILDS_AXIS = "builds"
"""Name of the mesh axis the Monte Carlo builds are split over."""


# ---------------------------------------------------------------------------------------
# launch settings


@dataclasses.dataclass(frozen=True)
class Launch:
    """Validated launch settings of one process (see :func:`check_launch`).

    Attributes:
        processes: local processes to spawn (``--processes``); 1 = no spawning.
        coordinator: ``"HOST:PORT"``, ``"auto"`` (JAX's cluster auto-detection, e.g.
            SLURM) or ``None`` (a single process, no runtime).
        num_processes: processes in the run (``None`` with ``"auto"``).
        process_id: this process's index ``0 … num_processes - 1`` (``None`` with
            ``"auto"``).
    """

    processes: int = 1
    coordinator: str | None = None
    num_processes: int | None = None
    process_id: int | None = None

    @property
    def spawns(self) -> bool:
        """True when this invocation only spawns local processes."""
        return self.processes > 1 and self.coordinator is None

    @property
    def distributed(self) -> bool:
        """True when this process joins a distributed runtime."""
        return self.coordinator is not None


def parse_coordinator(text: str) -> tuple[str, int]:
    """``"HOST:PORT"`` (IPv6 as ``"[ADDR]:PORT"``) -> ``(host, port)``; an input error
    naming ``--coordinator`` when it does not parse."""
    where = "--coordinator"
    expected = "HOST:PORT with PORT in 1…65535 (IPv6 as [ADDR]:PORT), or 'auto'"
    s = str(text).strip()
    if s.startswith("["):
        host, sep, rest = s[1:].partition("]")
        if not sep or not rest.startswith(":"):
            raise input_error(where, f"cannot parse {text!r}", expected)
        port_s = rest[1:]
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise input_error(where, f"{host!r} is not an IPv6 address", expected) from None
    else:
        host, sep, port_s = s.rpartition(":")
        if not sep or not host or ":" in host:
            raise input_error(where, f"cannot parse {text!r}", expected)
        ok = all(c.isalnum() or c in "-._" for c in host)
        if not ok:
            raise input_error(where, f"bad host name {host!r} in {text!r}", expected)
    if not port_s.isdigit() or not 1 <= int(port_s) <= 65535:
        raise input_error(where, f"bad port {port_s!r} in {text!r}", expected)
    return host, int(port_s)


MAX_LOCAL_PROCESSES = 1024
"""Most processes ``--processes N`` spawns on one machine."""
MAX_PROCESSES = 100_000
"""Most processes of a distributed run (``--num-processes``)."""


def check_launch(
    processes: int | None = None,
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
) -> Launch:
    """Validate the launch flags (input errors: exit status 2 at the CLI).

    ``processes`` (``--processes N``) spawns N local processes; ``coordinator``,
    ``num_processes``, ``process_id`` join a run on a cluster (all three, or
    ``coordinator="auto"`` alone for JAX's auto-detection, e.g. under SLURM).
    """
    procs = 1 if processes is None else processes
    if (
        isinstance(procs, bool)
        or not isinstance(procs, int)
        or not 1 <= procs <= MAX_LOCAL_PROCESSES
    ):
        raise input_error("--processes", f"{processes!r}", f"an integer 1 … {MAX_LOCAL_PROCESSES}")
    if coordinator is None:
        if num_processes is not None or process_id is not None:
            raise input_error(
                "--num-processes/--process-id", "given without --coordinator", "--coordinator"
            )
        return Launch(procs)
    if procs > 1:
        raise input_error(
            "--processes", "given together with --coordinator", "one of the two, not both"
        )
    if str(coordinator).strip().lower() == "auto":
        if num_processes is not None or process_id is not None:
            raise input_error(
                "--coordinator auto", "given with --num-processes/--process-id", "neither"
            )
        return Launch(1, "auto")
    parse_coordinator(coordinator)
    if num_processes is None or process_id is None:
        raise input_error(
            "--coordinator", "needs --num-processes N and --process-id I", "both flags"
        )
    n = num_processes
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_PROCESSES:
        raise input_error(
            "--num-processes", f"{num_processes!r}", f"an integer 1 … {MAX_PROCESSES}"
        )
    if not isinstance(process_id, int) or not 0 <= process_id < num_processes:
        raise input_error("--process-id", f"{process_id!r}", f"an integer in 0…{num_processes - 1}")
    return Launch(1, str(coordinator).strip(), num_processes, process_id)


def _wait_for_coordinator(host: str, port: int, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.getaddrinfo(host, port)
        except socket.gaierror as exc:
            raise input_error(
                "--coordinator", f"host {host!r} does not resolve ({exc})", "a reachable host"
            ) from None
        try:
            with socket.create_connection((host, port), timeout=1.0):
                return
        except OSError:
            if time.monotonic() > deadline:
                raise DistributedError(
                    f"coordinator {host}:{port} not reachable within {timeout_s:g} s "
                    "(is process 0 running, and the port open?)"
                ) from None
            time.sleep(0.2)


def _check_port_free(port: int) -> None:
    for family, addr in ((socket.AF_INET6, "::"), (socket.AF_INET, "0.0.0.0")):
        try:
            with socket.socket(family, socket.SOCK_STREAM) as s:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind((addr, port))
            return
        except OSError as exc:
            if family == socket.AF_INET6 and exc.errno in (97, 99):  # no IPv6 here
                continue
            raise DistributedError(f"coordinator port {port} is in use ({exc.strerror})") from None


def initialize(launch: Launch, *, timeout_s: float = 60.0, heartbeat_s: int = 20) -> None:
    """Join the distributed runtime described by ``launch`` (nothing for one process).

    Must run before any JAX computation. On CPU the collectives are gloo
    (``jax_cpu_collectives_implementation``). Process 0 hosts the coordinator; the others
    wait for it at most ``timeout_s`` (then :class:`DistributedError`). A process that
    stops sending heartbeats for ``heartbeat_s`` seconds makes the others stop.
    """
    if not launch.distributed:
        return
    if jax.distributed.is_initialized():
        return
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    if launch.coordinator == "auto":
        try:
            jax.distributed.initialize(
                initialization_timeout=int(timeout_s), heartbeat_timeout_seconds=heartbeat_s
            )
        except (ValueError, RuntimeError) as exc:
            raise DistributedError(f"cluster auto-detection failed: {exc}") from None
        _join_store()
        return
    if launch.coordinator is None:
        raise DistributedError("no coordinator address to join (--coordinator HOST:PORT)")
    host, port = parse_coordinator(launch.coordinator)
    if launch.process_id == 0:
        _check_port_free(port)
    else:
        _wait_for_coordinator(host, port, timeout_s)
    try:
        jax.distributed.initialize(
            coordinator_address=f"{host}:{port}" if ":" not in host else f"[{host}]:{port}",
            num_processes=launch.num_processes,
            process_id=launch.process_id,
            initialization_timeout=int(timeout_s),
            heartbeat_timeout_seconds=int(heartbeat_s),
        )
    except RuntimeError as exc:
        raise DistributedError(f"jax.distributed.initialize: {exc}") from None
    _join_store()


_RUNTIME: list[StoreGather] = []
"""The joined runtime's :class:`~._kv_gather.StoreGather` (none before :func:`initialize`
and after :func:`shutdown`): it owns the numbering of the gathers' keys in the store."""


def _join_store() -> None:
    """Hold a :class:`~._kv_gather.StoreGather` for the runtime just joined (none when its
    client cannot be reached: the gathers are then compiled, as before)."""
    from ._kv_gather import runtime_client

    _RUNTIME.clear()
    client, _why = runtime_client()
    if client is not None and jax.process_count() > 1:
        _RUNTIME.append(StoreGather(client, jax.process_index(), jax.process_count()))


def store_gather() -> StoreGather | None:
    """The joined runtime's store gatherer, if any (its counters: ``seq``, ``through_store``,
    ``compiled``)."""
    return _RUNTIME[0] if _RUNTIME else None


def _allgather(x: np.ndarray, name: str) -> np.ndarray:
    """``[process_count, *x.shape]``: every process's ``x`` (the same shape and dtype on all)
    in process order, through the store where it can (:mod:`._kv_gather`), else compiled."""
    g = store_gather()
    return compiled_allgather(x) if g is None else g.allgather(x, name)


def shutdown() -> None:
    """Leave the distributed runtime (a barrier: every process calls it)."""
    _RUNTIME.clear()
    if jax.distributed.is_initialized():
        jax.distributed.shutdown()


def process_index() -> int:
    """This process's index (0 without a runtime)."""
    return jax.process_index()


def process_count() -> int:
    """Processes in the run (1 without a runtime)."""
    return jax.process_count()


def is_main_process() -> bool:
    """True on process 0: the one that prints, shows progress and writes files."""
    return jax.process_index() == 0


# ---------------------------------------------------------------------------------------
# meshes and the sharded builds axis


@functools.lru_cache(maxsize=8)
def _mesh_of(devices: tuple[Any, ...]) -> Mesh:
    return Mesh(np.array(devices, dtype=object), (BUILDS_AXIS,))


def builds_mesh(local: bool = False) -> Mesh:
    """A one-axis mesh ``"builds"`` over all devices of all processes (``local``: of this
    process only)."""
    return _mesh_of(tuple(jax.local_devices() if local else jax.devices()))


def use_local_devices() -> contextlib.AbstractContextManager:
    """Context in which :func:`shard_builds` uses this process's devices only (for work
    each process does on its own, e.g. its share of sweep cases)."""
    return jax.set_mesh(builds_mesh(local=True))


def n_build_shards() -> int:
    """How many shards :func:`shard_builds` splits the builds into here and now."""
    am = jax.sharding.get_abstract_mesh()
    if BUILDS_AXIS in am.manual_axes:  # inside a shard_map over the builds: not split again
        return 1
    if BUILDS_AXIS in am.axis_names:
        return int(am.shape[BUILDS_AXIS])
    return len(jax.devices())


def shard_builds(
    local_fn: Callable[[jax.Array, int], jax.Array],
    n: int,
    *,
    manual: bool = False,
    gather: bool = True,
) -> jax.Array:
    """Traceable per-build values ``[n]``, the builds split over the ``"builds"`` mesh.

    ``local_fn(offset, m)`` returns the values ``[m]`` of builds ``offset … offset + m - 1``
    (``offset`` a traced integer, ``m`` static). With ``D`` shards each computes
    ``m = ceil(n / D)`` builds (the last ones past ``n`` are discarded), then the values are
    all-gathered so every device holds all ``n`` in build order. With one device this is
    just ``local_fn(0, n)``. Differentiable (the gather's transpose is a slice).

    ``manual=True`` uses ``jax.shard_map`` (each device runs only its slice: the fast path,
    used by :func:`~encdesign.design.monte_carlo`); it requires that ``local_fn`` closes
    over no array already laid out on a mesh. The default partitions a vmapped slice axis
    with GSPMD, which works for any closure (solver steps) but may communicate inside the
    loop.

    ``gather=False`` (``manual`` only, ``n`` a multiple of the shard count): no gather at
    all; the values stay where they were computed, an array ``[n]`` laid out over the
    mesh (:func:`gather_chunks` collects such arrays later, in one go).
    """
    n = int(n)
    am = jax.sharding.get_abstract_mesh()
    if BUILDS_AXIS in am.manual_axes:
        # already inside a shard_map over the builds (e.g. a user objective that estimates an
        # expectation, evaluated per build of monte_carlo): this device's slice runs here,
        # nothing is split again
        return local_fn(jnp.asarray(0, dtype=jnp.int32), n)
    if BUILDS_AXIS in am.axis_names:
        d = int(am.shape[BUILDS_AXIS])
        sharded, replicated = P(BUILDS_AXIS), P()
    else:
        devices = tuple(jax.devices())
        d = len(devices)
        if d > 1:
            mesh = _mesh_of(devices)
            sharded, replicated = NamedSharding(mesh, P(BUILDS_AXIS)), NamedSharding(mesh, P())
    if d <= 1:
        return local_fn(jnp.asarray(0, dtype=jnp.int32), n)
    m = -(-n // d)
    if not gather and (not manual or m * d != n):
        raise EncdesignInputError(
            f"gather=False needs manual=True and n={n} a multiple of {d} shards"
        )
    offsets = jnp.arange(d, dtype=jnp.int32) * m
    if manual:
        # shard_map: each device runs exactly its slice; nothing but the final gather
        # crosses devices or processes. Only for functions that close over no array
        # already laid out on the mesh (monte_carlo makes its inputs host arrays first).
        out = jax.shard_map(
            lambda off: local_fn(off[0], m),
            mesh=None if isinstance(sharded, P) else sharded.mesh,
            in_specs=P(BUILDS_AXIS),
            out_specs=P(BUILDS_AXIS),
        )(offsets)
        if not gather:
            return out
        return jax.lax.with_sharding_constraint(out, replicated)[:n]
    # traceable anywhere (inside solvers, whose designs are outputs on the mesh): the slices
    # are a batch axis laid out on the mesh and XLA's SPMD partitioner splits them. Same
    # values; but the partitioner may place collectives inside the build loop (seen around
    # the batched linear solve of self-compensation), which costs much across processes.
    offsets = jax.lax.with_sharding_constraint(offsets, sharded)
    vals = jax.vmap(lambda off: local_fn(off, m))(offsets)  # [d, m]
    vals = jax.lax.with_sharding_constraint(vals.reshape(-1), sharded)
    return jax.lax.with_sharding_constraint(vals, replicated)[:n]


def chunk_plan(n: int, chunk_size: int, shards: int, multiple: int = 1) -> tuple[int, int]:
    """``(block, n_chunks)`` for ``n`` builds on ``shards`` devices, at most ``chunk_size``
    builds per device and chunk: as few chunks as that allows, and the builds spread evenly
    over them (``block`` rounded up to a ``multiple`` when larger, never above
    ``chunk_size``), so that the padding costs at most ``multiple`` builds per device and
    chunk rather than up to a whole chunk (with one chunk size for every ``n``, 2 processes
    computed 2.4 % more builds than one at 100,000 builds, 4 processes 6.5 %)."""
    n, shards = int(n), max(int(shards), 1)
    cap = max(int(chunk_size), 1)
    n_chunks = max(-(-n // (shards * cap)), 1)
    block = -(-n // (n_chunks * shards))
    m = max(int(multiple), 1)
    if block > m:
        block = min(-(-block // m) * m, cap)
    return int(block), int(n_chunks)


@functools.lru_cache(maxsize=16)
def _replicate_on(mesh: Mesh) -> Callable[[jax.Array], jax.Array]:
    return jax.jit(lambda x: x, out_shardings=NamedSharding(mesh, P()))


def gather_chunks(chunks: Sequence[jax.Array]) -> np.ndarray:
    """Host copy of the concatenated ``chunks`` (each a 1-D array laid out over a mesh, as
    :func:`shard_builds` returns them with ``gather=False``), on every process.

    Called once, after every chunk has been dispatched: the processes then never wait for
    each other while they compute (a gather inside every chunk made each chunk wait for the
    slowest process, so any other load on either core slowed both), and the only
    collective is one all-gather per chunk at the end (8 bytes per build; a chunk's shape
    is fixed, so it is compiled once). Arrays this process holds entirely (one process, or
    a mesh of its own devices) are copied without any collective."""
    out = []
    for x in chunks:
        if x.is_fully_addressable:
            out.append(np.asarray(x))
        else:
            sharding = x.sharding
            if not isinstance(sharding, NamedSharding):
                raise DistributedError(f"a chunk laid out by {type(sharding).__name__}, not a mesh")
            rep = _replicate_on(sharding.mesh)(x)
            out.append(np.asarray(rep.addressable_data(0)))
    return np.concatenate(out) if out else np.zeros((0,))


def split_range(n: int, parts: int, part: int) -> tuple[int, int]:
    """Contiguous share ``[start, stop)`` of ``0 … n-1`` for ``part`` of ``parts``."""
    size = -(-int(n) // max(int(parts), 1))
    start = min(part * size, n)
    return start, min(start + size, n)


def allgather_rows(rows: np.ndarray, n_total: int, name: str = "rows") -> np.ndarray:
    """Concatenate every process's ``rows [m_p, k]`` (its :func:`split_range` share, in
    process order) into ``[n_total, k]`` on every process (one gather, ``name``)."""
    rows = np.asarray(rows, dtype=np.float64)
    if jax.process_count() == 1:
        return rows
    size = -(-int(n_total) // jax.process_count())
    k = int(np.prod(rows.shape[1:], dtype=np.int64))
    width = k if store_gather() is not None else bucket(k)  # compiled per shape: few shapes
    pad = np.full((size, width), np.nan)  # a row's values, then padding
    pad[: rows.shape[0], :k] = rows.reshape(rows.shape[0], k)
    got = _allgather(pad, name)
    return got.reshape(-1, pad.shape[1])[:n_total, :k].reshape(-1, *rows.shape[1:])


GATHER_ROWS = 1 << 20
"""Rows per process in one collective of :func:`allgather_concat` (bounds its temporaries)."""


def allgather_concat(rows: np.ndarray, counts: Sequence[int], name: str = "concat") -> np.ndarray:
    """Concatenate every process's ``rows [m_p, ...]`` in process order on every process,
    ``counts[p]`` being ``m_p`` (known to all, e.g. from :func:`allgather_objects`); the
    dtype is kept. The result is allocated once and filled by collectives of at most
    :data:`GATHER_ROWS` rows per process, so the temporaries stay within
    ``processes x GATHER_ROWS`` rows whatever the total."""
    rows = np.asarray(rows)
    if jax.process_count() == 1:
        return rows
    counts = [int(c) for c in counts]
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    out = np.empty((int(starts[-1]), *rows.shape[1:]), rows.dtype)
    step = min(GATHER_ROWS, max(max(counts), 1))
    for a in range(0, max(max(counts), 1), step):
        pad = np.zeros((step, *rows.shape[1:]), rows.dtype)
        mine = rows[a : a + step]
        pad[: mine.shape[0]] = mine
        got = _allgather(pad, name)
        for p, c in enumerate(counts):
            k = max(0, min(step, c - a))
            out[starts[p] + a : starts[p] + a + k] = got[p, :k]
        del got, pad
    return out


def allgather_objects(items: Sequence[Any], name: str = "objects") -> list[Any]:
    """Every process's list of JSON-able ``items`` (its share of tasks, e.g. benchmark rows),
    concatenated in process order on every process (two collectives: lengths, then bytes).
    NumPy scalars and arrays become Python numbers and lists."""
    items = list(items)
    if jax.process_count() == 1:
        return items
    import json

    def plain(x: Any) -> Any:
        if isinstance(x, np.ndarray):
            return x.tolist()
        if isinstance(x, np.generic):
            return x.item()
        raise TypeError(f"not JSON-able: {type(x).__name__}")

    out: list[Any] = []
    for blob in allgather_bytes(json.dumps(items, default=plain).encode("utf-8"), name):
        out += json.loads(blob.decode("utf-8"))
    return out


SMALL_GATHER_BYTES = 1 << 13
"""The least :func:`allgather_bytes` pads to where there is no key-value store to use: the
small gathers of a diagnosis (flags, counts, edges, a few KiB at most) then share one
compiled program instead of one per size."""


def allgather_bytes(data: bytes, name: str = "bytes") -> list[bytes]:
    """Every process's ``data``, in process order, on every process (:mod:`._kv_gather`:
    through the runtime's key-value store when every process's is small, else in pieces
    through its one compiled gather; without the store, two compiled collectives: sizes, then
    the bytes padded to the largest's :func:`bucket`, at least :data:`SMALL_GATHER_BYTES`)."""
    g = store_gather()
    if g is None:
        return padded_bytes_allgather(data, SMALL_GATHER_BYTES)
    return g.allgather_bytes(data, name)


def is_my_task(i: int) -> bool:
    """True when task ``i`` (of a list every process enumerates in the same order) is this
    process's: tasks are dealt round-robin, ``i mod process_count == process_index``."""
    return int(i) % jax.process_count() == jax.process_index()


def barrier(name: str) -> None:
    """Wait until every process reaches the barrier ``name`` (no-op for one process)."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


# ---------------------------------------------------------------------------------------
# local spawning (--processes N)


def free_port() -> int:
    """A TCP port free on localhost right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def spawn_local(
    argv: Sequence[str],
    processes: int,
    *,
    env: dict[str, str] | None = None,
    grace_s: float = 30.0,
    timeout_s: float | None = None,
    program: Sequence[str] | None = None,
) -> int:
    """Run ``python -m encdesign ARGV --coordinator localhost:PORT --num-processes N
    --process-id I`` for ``I = 0 … N-1`` and wait for them.

    Process 0's output is shown; the others' stderr is kept and shown when they fail. When
    a process exits with a crash (status other than 0, 1, 2) every other process is stopped
    at once; after an ordinary failure (1, 2) the others get ``grace_s`` to finish. Returns
    process 0's exit status, or 1 after a crash or ``timeout_s``. ``program`` replaces
    ``python -m encdesign`` (any program that takes the launch flags).
    """
    port = free_port()
    prog = [sys.executable, "-m", "encdesign"] if program is None else list(program)
    base = [*prog, *argv]
    extra = ["--coordinator", f"localhost:{port}", "--num-processes", str(processes)]
    penv = dict(os.environ if env is None else env)
    penv.setdefault("PYTHONUNBUFFERED", "1")
    if not penv.get(_cpu.ENV) and not penv.get("OMP_NUM_THREADS"):
        # the cores are shared: each process gets its part of encdesign's CPU devices
        penv[_cpu.ENV] = str(max(1, _cpu.cores() // processes))
    logs, procs = [], []
    try:
        for i in range(processes):
            log = tempfile.TemporaryFile(mode="w+b")
            logs.append(log)
            procs.append(
                subprocess.Popen(
                    [*base, *extra, "--process-id", str(i)],
                    env=penv,
                    stdout=None if i == 0 else subprocess.DEVNULL,
                    stderr=None if i == 0 else log,
                    start_new_session=True,
                )
            )
        return _wait_all(procs, logs, grace_s, timeout_s)
    finally:
        for p in procs:
            _stop(p)
        for log in logs:
            log.close()


def _stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGTERM)
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def _wait_all(procs, logs, grace_s: float, timeout_s: float | None) -> int:
    t0 = time.monotonic()
    deadline = None
    crashed: tuple[int, int] | None = None
    while True:
        codes = [p.poll() for p in procs]
        if all(c is not None for c in codes):
            break
        for i, c in enumerate(codes):
            if c is not None and c not in (0, 1, 2) and crashed is None:
                crashed = (i, c)
            elif c is not None and c != 0 and deadline is None:
                deadline = time.monotonic() + grace_s
        now = time.monotonic()
        late = deadline is not None and now > deadline
        if crashed is not None or late or (timeout_s is not None and now - t0 > timeout_s):
            break
        time.sleep(0.05)
    for p in procs:
        _stop(p)
    codes = [p.returncode for p in procs]
    if crashed is None:
        bad = [(i, c) for i, c in enumerate(codes) if c not in (0, 1, 2)]
        crashed = bad[0] if bad else None
    if crashed is not None:
        i, c = crashed
        why = f"signal {-c}" if c < 0 else f"status {c}"
        print(
            f"encdesign: process {i} of {len(procs)} failed ({why}); stopped the others",
            file=sys.stderr,
        )
        if i > 0:
            logs[i].seek(0)
            tail = logs[i].read()[-4000:].decode("utf-8", "replace")
            print(f"--- process {i} stderr (tail) ---\n{tail}", file=sys.stderr)
        return 1
    if timeout_s is not None and any(c is None for c in codes):
        print(f"encdesign: processes did not finish within {timeout_s:g} s", file=sys.stderr)
        return 1
    return int(codes[0])


# ---------------------------------------------------------------------------------------
# CLI glue


def add_launch_flags(parser: Any) -> None:
    """The ``--processes`` / ``--coordinator`` / ``--num-processes`` / ``--process-id`` flags
    (``docs/scale.md``)."""
    g = parser.add_argument_group("scale-out (docs/scale.md)")
    g.add_argument(
        "--processes",
        type=int_arg(1, MAX_LOCAL_PROCESSES),
        default=None,
        metavar="N",
        help=f"spawn N local processes (1 … {MAX_LOCAL_PROCESSES}) with a coordinator on localhost",
    )
    g.add_argument(
        "--coordinator",
        default=None,
        metavar="HOST:PORT",
        help="join a distributed run (process 0 listens there); 'auto': JAX's cluster "
        "auto-detection (SLURM, Open MPI, ...)",
    )
    g.add_argument(
        "--num-processes",
        type=int_arg(1, MAX_PROCESSES),
        default=None,
        metavar="N",
        help=f"processes of the distributed run (1 … {MAX_PROCESSES})",
    )
    g.add_argument(
        "--process-id",
        type=int_arg(0, MAX_PROCESSES - 1),
        default=None,
        metavar="I",
        help="this process's index, 0 … N-1",
    )


def launch_from_args(args: Any) -> Launch:
    """Validated :class:`Launch` from parsed :func:`add_launch_flags` flags."""
    return check_launch(
        getattr(args, "processes", None),
        getattr(args, "coordinator", None),
        getattr(args, "num_processes", None),
        getattr(args, "process_id", None),
    )


def strip_launch_flags(argv: Sequence[str]) -> list[str]:
    """``argv`` without ``--processes N`` (also ``--processes=N``)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
            continue
        if a == "--processes":
            skip = True
            continue
        if a.startswith("--processes="):
            continue
        out.append(a)
    return out


def start(args: Any, argv: Sequence[str]) -> int | None:
    """Start what a command's launch flags (:func:`add_launch_flags`) ask for.

    With ``--processes N``: spawn the N local copies of ``argv`` and return their exit code
    (this process does no work itself). Otherwise join the runtime (with one process there is
    nothing to join) and return ``None``: the caller does its work, then calls
    :func:`shutdown`. A runtime that cannot be joined is printed and returned as exit code 1.
    Nothing here calls back into the caller: the CLI and the studies run their own work.
    """
    launch = launch_from_args(args)
    if launch.spawns:
        return spawn_local(strip_launch_flags(argv), launch.processes)
    try:
        initialize(launch)
    except DistributedError as exc:
        print(f"encdesign: error: {exc}", file=sys.stderr)
        return 1
    return None


def study_argv_for_this_process(name: str, flags: Sequence[str]) -> list[str]:
    """A study's flags for this process: unchanged on process 0; on the others ``--json`` is
    dropped, ``--no-plots`` added and ``--out DIR`` becomes ``DIR/.process-K`` (their
    duplicate summaries and, for the conceal benchmark, the recordings of their share)."""
    if is_main_process():
        return list(flags)
    out, it, out_dir = [], iter(flags), str(Path("results") / name)
    for a in it:
        if a == "--json":
            next(it, None)
        elif a.startswith("--json="):
            continue
        elif a == "--out":
            out_dir = next(it, out_dir)
        elif a.startswith("--out="):
            out_dir = a.split("=", 1)[1]
        elif a != "--no-plots":
            out.append(a)
    k = process_index()
    return [*out, "--out", str(Path(out_dir) / f".process-{k}"), "--no-plots"]


@contextlib.contextmanager
def quiet_unless_main() -> Iterator[None]:
    """Silence stdout on processes other than 0 (they compute, process 0 reports)."""
    if is_main_process():
        yield
        return
    with open(os.devnull, "w") as null, contextlib.redirect_stdout(null):
        yield
