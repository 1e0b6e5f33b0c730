"""All-gathers of the scale-out runtime: small ones through its key-value store, the rest
through one compiled program (issue 43).

:func:`jax.experimental.multihost_utils.process_allgather` runs an XLA program, compiled
once per shape and process (30-80 ms of CPU on a 2-core machine). A diagnosis split over
two processes at 10^7 rows gathered arrays of 13 shapes: 13 of the 29 programs each process
compiled. Here they compile one program, and the block means of a long record's read one
more:

* an array of at most :data:`KV_BYTES_MAX` bytes a process goes through the coordinator's
  key-value store (``jax.distributed``'s client: ``key_value_set_bytes``,
  ``blocking_key_value_get_bytes``): about 1-2 ms a gather and nothing compiled;
* a larger one, up to :data:`WHOLE_BYTES`, is cut into pieces of :data:`CHUNK_BYTES` and
  every piece goes through the same compiled all-gather (``int64[CHUNK_BYTES / 8]``): one
  program for all of them. The store is no route for them: measured on 2 processes, 256 KiB
  took 17 ms through the store and 1.3 ms compiled (after the compilation), 1 MiB 109 ms
  against 10 ms;
* a larger one still (a step of the block means a long record's read gathers, all of one
  shape) goes whole through a compiled all-gather of its own shape, as ``int64``.

Either way every process receives every process's bytes unchanged, so nothing computed from
a gather depends on the path it took.

**The keys and their lifetime.** A :class:`StoreGather` is made when the runtime is joined
(:func:`encdesign._distributed.initialize`) and dropped when it is left; it numbers its
gathers ``0, 1, 2, ...``. Every process makes the same gathers in the same order (as for any
collective), so gather ``s`` has one key on each process ``p``,
``encdesign/gather/p/f/s`` (``f = s //`` :data:`KEYS_PER_FOLDER`). Each
gather, whatever its route, first passes a header through the store: the gather's name, the
array's shape and dtype (or ``bytes``) and its size, then the bytes themselves where they are
small. A process that finds another's header different from its own raises
:class:`~encdesign.DistributedError` naming both (the processes went out of step) instead of
waiting forever for a key nobody writes or a collective nobody joins: the name is in the
value, not in the key, so that processes out of step still meet at the same key. A process
deletes its folder ``f - 1`` (one call) once it has read every key of gather
``s = f x KEYS_PER_FOLDER``: every other process wrote its key of ``s``, so it has read all
keys of the gathers before. No barrier, and the store holds at most ``KEYS_PER_FOLDER + 2``
keys a process whatever the length of the run.

**The client.** JAX 0.10.2 has no public way to the runtime's client (``jax.distributed``
exports ``initialize``, ``is_initialized`` and ``shutdown`` only); :func:`runtime_client` is
the one place that reaches it, through ``jax._src.distributed.global_state.client`` (as
``jax.experimental.multihost_utils`` itself does), and checks that it has the methods used
here. Where it does not (another JAX), it says why, and the gathers are compiled per shape as
before.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from ._errors import DistributedError

KV_BYTES_MAX = 1 << 15
"""The largest array (bytes per process) gathered through the key-value store."""

CHUNK_BYTES = 1 << 20
"""The bytes a process sends in one call of the one compiled all-gather of larger arrays."""

WHOLE_BYTES = 1 << 22
"""An array of more bytes than this a process goes whole through a compiled all-gather of
its own shape (the block means of a long record's read, cut into steps of one shape by
:func:`~encdesign._distributed.allgather_concat`): pieces cost more calls than one compiled
program."""

TIMEOUT_MS = 24 * 3600 * 1000
"""How long a process waits for another's key of the same gather (a process that dies
stops the others sooner, through the runtime's heartbeat)."""

PREFIX = "encdesign/gather/"
"""The keys' prefix in the store (the store is the run's: its coordinator is process 0)."""


class KeyValueClient(Protocol):
    """The methods of ``jax.distributed``'s runtime client that :class:`StoreGather` uses."""

    def key_value_set_bytes(self, key: str, value: bytes, allow_overwrite: bool = False) -> None:
        """Set ``key`` (an error if it is set, unless ``allow_overwrite``)."""
        ...

    def blocking_key_value_get_bytes(self, key: str, timeout_in_ms: int) -> bytes:
        """The value of ``key``, waiting for it at most ``timeout_in_ms``."""
        ...

    def key_value_delete(self, key: str) -> None:
        """Delete ``key``."""
        ...


_METHODS = ("key_value_set_bytes", "blocking_key_value_get_bytes", "key_value_delete")


def runtime_client() -> tuple[KeyValueClient | None, str]:
    """``(client, "")``: the joined runtime's key-value client; ``(None, why)`` when there
    is none to use (no runtime joined, or a JAX whose client lacks the methods used)."""
    import jax

    try:
        from jax._src import distributed
    except ImportError as exc:  # pragma: no cover - another JAX layout
        return None, f"jax {jax.__version__}: no jax._src.distributed ({exc})"
    client = getattr(getattr(distributed, "global_state", None), "client", None)
    if client is None:
        return None, "no distributed runtime joined"
    missing = [m for m in _METHODS if not callable(getattr(client, m, None))]
    if missing:
        return None, f"jax {jax.__version__}: the runtime's client lacks {', '.join(missing)}"
    return client, ""


class StoreGather:
    """The all-gathers of one joined runtime through its key-value store (see the module's
    text): ``seq`` numbers the gathers made so far; ``through_store`` and ``compiled``
    count those whose bytes went through the store and through the compiled pieces."""

    def __init__(
        self,
        client: KeyValueClient,
        process_index: int,
        process_count: int,
        *,
        max_bytes: int = KV_BYTES_MAX,
        chunk_bytes: int = CHUNK_BYTES,
        whole_bytes: int = WHOLE_BYTES,
        timeout_ms: int = TIMEOUT_MS,
    ) -> None:
        self.client = client
        self.me = int(process_index)
        self.n = int(process_count)
        self.max_bytes = int(max_bytes)
        self.chunk_bytes = -(-int(chunk_bytes) // 8) * 8
        self.whole_bytes = int(whole_bytes)
        self.timeout_ms = int(timeout_ms)
        self.seq = 0
        self.through_store = 0
        self.compiled = 0

    def _round(
        self, name: str, sig: str, payload: bytes, inline: bool
    ) -> tuple[list[int], list[bytes | None]]:
        """One gather: this process's header and (``inline``) ``payload`` out, every
        process's in: the payloads' sizes, and each payload or ``None`` where its process
        sent only the header. Raises :class:`DistributedError` when another process made a
        different gather."""
        if "|" in name or "\n" in name:
            raise ValueError(f"a gather's name without '|' or newlines, not {name!r}")
        seq = self.seq
        self.seq += 1
        head = f"{name}|{sig}|{len(payload)}|{int(inline)}\n".encode()
        self.client.key_value_set_bytes(_key(self.me, seq), head + (payload if inline else b""))
        sizes: list[int] = []
        out: list[bytes | None] = []
        for p in range(self.n):
            if p == self.me:
                sizes.append(len(payload))
                out.append(payload if inline else None)
                continue
            try:
                blob = self.client.blocking_key_value_get_bytes(_key(p, seq), self.timeout_ms)
            except Exception as exc:  # the runtime's own error (a timeout, a dead process)
                raise DistributedError(
                    f"gather {seq} ({name!r}): process {self.me} got nothing from process "
                    f"{p}: {exc}"
                ) from None
            their_head, _, body = blob.partition(b"\n")
            t_name, t_sig, t_size, t_inline = their_head.decode().split("|")
            if (t_name, t_sig) != (name, sig):
                raise DistributedError(
                    f"gather {seq}: process {self.me} gathers {name!r} ({sig}) but process "
                    f"{p} gathers {t_name!r} ({t_sig}): the processes' collectives are out of "
                    "step (every process must make the same gathers in the same order)"
                )
            if t_inline == "1" and len(body) != int(t_size):
                raise DistributedError(f"gather {seq} ({name!r}): process {p}'s value truncated")
            sizes.append(int(t_size))
            out.append(body if t_inline == "1" else None)
        if seq % KEYS_PER_FOLDER == 0 and seq > 0:  # every process is past the last folder
            self.client.key_value_delete(_folder(self.me, seq // KEYS_PER_FOLDER - 1))
        return sizes, out

    def allgather(self, x: np.ndarray, name: str) -> np.ndarray:
        """``[process_count, *x.shape]``: every process's ``x`` (the same shape and dtype on
        every process) stacked in process order, on every process."""
        x = np.ascontiguousarray(x)
        sig = f"{x.dtype.str}{list(x.shape)}"
        raw = x.reshape(-1).view(np.uint8)
        inline = x.nbytes <= self.max_bytes  # the same on every process (same shape)
        _, got = self._round(name, sig, raw.tobytes() if inline else b"", inline)
        if inline:
            self.through_store += 1
            out = np.empty((self.n, *x.shape), x.dtype)
            for p, blob in enumerate(got):
                out[p] = x if p == self.me else np.frombuffer(blob or b"", x.dtype).reshape(x.shape)
            return out
        self.compiled += 1
        if x.nbytes > self.whole_bytes and x.nbytes % 8 == 0:  # one piece: its own program
            every = compiled_allgather(raw.view(np.int64)).view(np.uint8)
        else:
            every = pieces_allgather(raw, [x.nbytes] * self.n, self.chunk_bytes)
        return every.view(x.dtype).reshape(self.n, *x.shape)

    def allgather_bytes(self, data: bytes, name: str) -> list[bytes]:
        """Every process's ``data`` (any length) in process order, on every process: through
        the store when every process's is at most ``max_bytes``, else in compiled pieces."""
        data = bytes(data)
        sizes, got = self._round(name, "bytes", data, len(data) <= self.max_bytes)
        if all(g is not None for g in got):
            self.through_store += 1
            return [g or b"" for g in got]
        self.compiled += 1
        every = pieces_allgather(np.frombuffer(data, np.uint8), sizes, self.chunk_bytes)
        return [every[p, :n].tobytes() for p, n in enumerate(sizes)]


KEYS_PER_FOLDER = 16
"""Gathers whose keys of one process share a folder of the store (deleted in one go)."""


def _folder(process: int, folder: int) -> str:
    return f"{PREFIX}{process}/{folder}/"


def _key(process: int, seq: int) -> str:
    """Process ``process``'s key of gather ``seq``."""
    return f"{_folder(process, seq // KEYS_PER_FOLDER)}{seq}"


def pieces_allgather(raw: np.ndarray, sizes: Sequence[int], chunk_bytes: int) -> np.ndarray:
    """``uint8[processes, max(sizes)]``: every process's bytes ``raw`` (``sizes[p]`` on
    process ``p``, known to all; the rest of a row zeros) in process order, through one
    compiled all-gather of ``int64[chunk_bytes / 8]`` called once per piece of
    ``chunk_bytes`` of the largest."""
    m = max(int(n) for n in sizes)
    out = np.zeros((len(sizes), m), np.uint8)
    pad = np.zeros(chunk_bytes // 8, np.int64)
    buf = pad.view(np.uint8)
    for a in range(0, max(m, 1), chunk_bytes):
        k = max(0, min(chunk_bytes, raw.size - a))
        buf[:k] = raw[a : a + k]
        buf[k:] = 0
        got = compiled_allgather(pad).view(np.uint8).reshape(len(sizes), chunk_bytes)
        e = min(m, a + chunk_bytes)
        out[:, a:e] = got[:, : e - a]
    return out


def bucket(n: int) -> int:
    """The length a collective of ``n`` values is padded to: the next ``2^j`` or
    ``3 * 2^(j - 1)`` (at least 1; half as much again at most). Each shape of a compiled
    collective is compiled once per process (some 10-50 ms of CPU); a record's row passes
    gather sums of many sizes, and padded so they need a few programs, not one per size."""
    p = 1 << max(int(n) - 1, 0).bit_length()  # the next power of two
    return 3 * p // 4 if p >= 4 and 3 * p // 4 >= n else p


def compiled_allgather(x: np.ndarray) -> np.ndarray:
    """``process_allgather(x)`` as a NumPy array (one compiled program per shape)."""
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(x))


def padded_bytes_allgather(data: bytes, least: int) -> list[bytes]:
    """Every process's ``data`` through compiled gathers (one program per shape: where there
    is no store): the sizes, then the bytes padded to the largest's :func:`bucket`, at least
    ``least``."""
    buf = np.frombuffer(data, dtype=np.uint8)
    sizes = compiled_allgather(np.array([buf.size], np.int64))
    pad = np.zeros(max(bucket(int(sizes.max())), int(least)), np.uint8)
    pad[: buf.size] = buf
    got = compiled_allgather(pad)
    return [bytes(row[: int(n)]) for row, n in zip(got, sizes.reshape(-1))]
