"""Output paths: checked before any work, written atomically, never over an input.

Every file a command writes goes through :func:`atomic_output` (or the helpers built on
it): the content is written to a temporary file in the destination folder and renamed
into place only when complete, so a reader never sees half a file and a failure leaves
the old file (or nothing) behind.

:func:`check_outputs` is what commands call *before* computing anything. It refuses
(:class:`~encdesign.EncdesignInputError`, exit status 2):

* an output that is, by path or by resolved identity (symbolic and hard links), one of
  the command's inputs or another of its outputs;
* an output that is an existing folder or another non-file (a device, a FIFO), an
  existing read-only file, or lies under a file or in a folder that cannot be written.

:class:`OutputGuard` remembers which outputs and folders did not exist before the command
ran and removes them again when the command fails, so a refusal leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gzip
import os
import stat
import tempfile
import tomllib
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from .._errors import input_error

__all__ = [
    "OutputGuard",
    "atomic_output",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_outputs",
    "recording_input_files",
    "recording_output_files",
]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(
    path: str | os.PathLike,
    mode: str = "w",
    *,
    encoding: str | None = "utf-8",
    newline: str | None = None,
    compress: bool = False,
) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path``; rename it onto ``path`` when the block ends.

    Args:
        path: the destination file (its folder is created when missing).
        mode: ``"w"`` (text) or ``"wb"`` (bytes).
        encoding, newline: text-mode options.
        compress: write gzip-compressed data.

    The file gets the usual permissions (``0o666`` less the umask), not ``mkstemp``'s
    ``0o600``. If the block raises, the temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    binary = "b" in mode
    try:
        if compress:
            gz_mode = "wb" if binary else "wt"
            kw = {} if binary else {"encoding": encoding, "newline": newline}
            fh = gzip.open(tmp, gz_mode, **kw)
        elif binary:
            fh = open(tmp, "wb")  # noqa: SIM115
        else:
            fh = open(tmp, "w", encoding=encoding, newline=newline)  # noqa: SIM115
        with fh:
            yield fh
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def atomic_write_text(path: str | os.PathLike, text: str, *, newline: str | None = None) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    with atomic_output(path, "w", newline=newline) as fh:
        fh.write(text)
    return Path(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_output(path, "wb") as fh:
        fh.write(data)
    return Path(path)


# ----------------------------------------------------------------------------- names


def recording_output_files(
    path: str | os.PathLike,
    *,
    compress: bool = False,
    parquet: bool = False,
    data_name: str | None = None,
    label: str | None = None,
) -> list[Path]:
    """The files a recording written at ``path`` consists of: the TOML and its table.

    ``label``: the flag or argument that named ``path`` (``--out``), for the message.
    ``compress``: a ``.csv.gz`` table; ``parquet``: a ``.parquet`` table.

    Raises:
        EncdesignInputError: ``path`` does not end in ``.toml`` (the table name is derived
            from it, and ``sim.csv`` would name the TOML and its own table alike).
    """
    path = Path(path)
    if path.suffix.lower() != ".toml":
        raise input_error(
            f"{label} {path}" if label else str(path),
            "a recording is written as NAME.toml (its table beside it)",
            "a .toml path",
        )
    if data_name is None:
        data_name = path.stem + (".parquet" if parquet else ".csv.gz" if compress else ".csv")
    return [path, path.parent / data_name]


def recording_input_files(path: str | os.PathLike) -> list[Path]:
    """The recording TOML and, when it can be read, the data table it names.

    Used to protect every file of an input recording; a TOML that cannot be read is
    refused later by the loader with its own message.
    """
    path = Path(path)
    files = [path]
    try:
        with open(path, "rb") as fh:
            meta = tomllib.loads(fh.read(1 << 24).decode("utf-8-sig"))
    except (OSError, ValueError, RecursionError):  # the loader reports it properly
        return files
    data = meta.get("data") if isinstance(meta, dict) else None
    if isinstance(data, str) and data:
        files.append(path.parent / data)
    return files


# ----------------------------------------------------------------------------- checks


def _identity(path: Path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return (st.st_dev, st.st_ino)


def _real(path: Path) -> str:
    return os.path.realpath(os.path.abspath(path))


def _nearest_existing(path: Path) -> Path:
    p = Path(os.path.abspath(path)).parent
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _writable_dir(d: Path) -> bool:
    try:
        fd, probe = tempfile.mkstemp(dir=d, prefix=".encdesign-probe-")
    except OSError:
        return False
    os.close(fd)
    os.remove(probe)
    return True


@dataclasses.dataclass(frozen=True)
class _Named:
    label: str
    path: Path

    def where(self) -> str:
        return f"{self.label} {self.path}" if self.label else str(self.path)


def _check_one(out: _Named) -> None:
    p = out.path
    where = out.where()
    if str(p) == "" or p.name in ("", ".", ".."):
        raise input_error(where, "not a file name", "a path to a file")
    if os.path.lexists(p):
        if os.path.islink(p) and not os.path.exists(p):
            raise input_error(where, "is a dangling symbolic link", "a file path")
        st = os.stat(p)
        if stat.S_ISDIR(st.st_mode):
            raise input_error(where, "is a folder", "a file path")
        if not stat.S_ISREG(st.st_mode):
            raise input_error(where, "exists and is not a regular file", "a file path")
        if not st.st_mode & 0o222:
            raise input_error(where, "is a read-only file", "a writable path")
    anc = _nearest_existing(p)
    if not anc.is_dir():
        raise input_error(where, f"{anc} is not a folder", "a path inside a folder")
    if not _writable_dir(anc):
        raise input_error(where, f"folder {anc} cannot be written", "a writable folder")


def check_outputs(
    inputs: Sequence[tuple[str, str | os.PathLike]],
    outputs: Sequence[tuple[str, str | os.PathLike]],
) -> None:
    """Refuse outputs that would destroy an input or another output, or cannot be written.

    Args:
        inputs: ``(label, path)`` of every file the command reads (``label`` names the
            argument, e.g. ``"recording"`` or ``"--like"``; derived files such as a
            recording's table included).
        outputs: ``(label, path)`` of every file it will write (derived files included).

    Raises:
        EncdesignInputError: naming the output and the input (or output) it clashes with.
    """
    ins = [_Named(lab, Path(p)) for lab, p in inputs]
    outs = [_Named(lab, Path(p)) for lab, p in outputs]
    for o in outs:
        _check_one(o)
    in_ids = [(i, _identity(i.path), _real(i.path)) for i in ins]
    seen: list[tuple[_Named, tuple[int, int] | None, str]] = []
    for o in outs:
        oid, oreal = _identity(o.path), _real(o.path)
        for i, iid, ireal in in_ids:
            if oreal == ireal or (oid is not None and oid == iid):
                raise input_error(
                    o.where(),
                    f"is the input {i.where()}" + ("" if oreal == ireal else " (a link to it)"),
                    "an output path that is none of the inputs",
                )
        for s, sid, sreal in seen:
            if oreal == sreal or (oid is not None and oid == sid):
                raise input_error(
                    o.where(),
                    f"is also the output {s.where()}",
                    "a different path for every output",
                )
        seen.append((o, oid, oreal))


class OutputGuard:
    """Remove what a failed command created: new output files and new folders.

    Use as a context manager around the command after :func:`check_outputs`::

        with OutputGuard(paths):
            ...compute and write...

    On an exception, every path in ``paths`` that did not exist on entry is removed, then
    every folder that did not exist on entry and is empty again. Files that existed are
    only ever replaced atomically by the writers, never removed.
    """

    def __init__(
        self, paths: Sequence[str | os.PathLike], folders: Sequence[str | os.PathLike] = ()
    ):
        self.paths = [Path(p) for p in paths]
        self.new_files = [p for p in self.paths if not os.path.lexists(p)]
        dirs: list[Path] = []
        for p in [*self.paths, *(Path(f) / "x" for f in folders)]:
            d = Path(os.path.abspath(p)).parent
            while not d.exists() and d != d.parent:
                if d not in dirs:
                    dirs.append(d)
                d = d.parent
        self.new_dirs = sorted(dirs, key=lambda d: len(d.parts), reverse=True)
        self.new_folder_outputs = [Path(f) for f in folders if not os.path.lexists(f)]

    def __enter__(self) -> OutputGuard:
        return self

    def cleanup(self) -> None:
        """Remove the new files and the new (empty) folders."""
        for p in self.new_files:
            with contextlib.suppress(OSError):
                if p.is_file() or p.is_symlink():
                    p.unlink()
        for f in self.new_folder_outputs:
            with contextlib.suppress(OSError):
                if f.is_dir():
                    for child in f.iterdir():
                        if child.is_file():
                            child.unlink()
        for d in self.new_dirs:
            with contextlib.suppress(OSError):
                d.rmdir()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None:
            self.cleanup()


def check_output_folder(
    label: str,
    path: str | os.PathLike,
    inputs: Sequence[tuple[str, str | os.PathLike]] = (),
    outputs: Sequence[tuple[str, str | os.PathLike]] = (),
) -> None:
    """Refuse an output folder that is a file, an input, or cannot be created or written."""
    p = Path(path)
    where = f"{label} {p}" if label else str(p)
    if os.path.lexists(p) and not os.path.isdir(p):
        raise input_error(where, "exists and is not a folder", "a folder path")
    real = _real(p)
    for lab, q in [*inputs, *outputs]:
        if _real(Path(q)) == real:
            raise input_error(where, f"is also {lab} {q}", "a folder of its own")
    anc = p if p.is_dir() else _nearest_existing(p)
    if not anc.is_dir():
        raise input_error(where, f"{anc} is not a folder", "a path inside a folder")
    if not _writable_dir(anc):
        raise input_error(where, f"folder {anc} cannot be written", "a writable folder")
