"""Case recording: every evaluated design (inputs, outputs, status, seed) in a file.

Two formats, chosen by the file suffix:

* ``.jsonl`` — one JSON object per line:
  ``{"case": 0, "status": "success", "seed": 0, "inputs": {...}, "outputs": {...}}``.
* ``.csv`` — columns ``case, status, seed, in.<name>…, out.<name>…``; every cell holds the
  JSON encoding of its value (so ``1`` stays an int, ``1.0`` a float, ``"a"`` a string).

Floats are written with Python's shortest round-trip representation, so
:func:`read_cases` returns exactly the numbers that were recorded. Non-finite outputs are
written as ``null`` and read back as ``nan`` (the case's ``status`` says why). Files are
written atomically (temporary file renamed into place).
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import math
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._errors import EncdesignInputError, input_error
from ..io._paths import atomic_write_text

if TYPE_CHECKING:
    from ._problem import Problem

FORMATS = (".jsonl", ".csv")


@dataclasses.dataclass(frozen=True)
class Case:
    """One evaluated design.

    Attributes:
        case: running index of the case in its file.
        inputs: variable name -> value (SI units; names carry units where ambiguous).
        outputs: output name -> value (SI units).
        status: driver status of the evaluation (``"success"``, ``"nonfinite"``, …).
        seed: PRNG seed used for the evaluation (``None`` when deterministic).
    """

    case: int
    inputs: dict[str, Any]
    outputs: dict[str, Any]
    status: str
    seed: int | None = None
    check: str | None = dataclasses.field(default=None, compare=False)
    """The checksum read from the file (:func:`case_check`; ``None`` when it had none)."""


def _plain(x: object) -> object:
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    if hasattr(x, "__array__") and not isinstance(x, str | bytes):
        arr = np.asarray(x)
        return _plain(arr.item()) if arr.ndim == 0 else [_plain(v) for v in arr.tolist()]
    if isinstance(x, np.generic):
        return _plain(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _restore(x: object) -> object:
    if x is None:
        return math.nan
    if isinstance(x, list):
        return [_restore(v) for v in x]
    return x


def case_check(c: Case) -> str:
    """The checksum written with every case line: SHA-256 (first 16 hex digits) of its
    inputs, outputs, status and seed. ``--resume`` refuses a line whose checksum does not
    match (a value edited by hand, a truncated or corrupted line)."""
    text = json.dumps(
        {
            "inputs": _plain(c.inputs),
            "outputs": _plain(c.outputs),
            "status": c.status,
            "seed": c.seed,
        },
        sort_keys=True,
        allow_nan=False,
    )
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _fmt(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise input_error(str(path), f"unknown case-file suffix {suffix!r}", "'.jsonl' or '.csv'")
    return suffix


def _atomic_write(path: Path, text: str) -> None:
    atomic_write_text(path, text, newline="")


def cases_text(cases: Iterable[Case], fmt: str) -> str:
    """The file content for ``cases`` in format ``".jsonl"`` or ``".csv"``."""
    cases = list(cases)
    if fmt == ".jsonl":
        lines = [
            json.dumps(
                {
                    "case": c.case,
                    "status": c.status,
                    "seed": c.seed,
                    "inputs": _plain(c.inputs),
                    "outputs": _plain(c.outputs),
                    "check": case_check(c),
                },
                allow_nan=False,
            )
            for c in cases
        ]
        return "".join(line + "\n" for line in lines)
    in_names: list[str] = []
    out_names: list[str] = []
    for c in cases:
        in_names += [k for k in c.inputs if k not in in_names]
        out_names += [k for k in c.outputs if k not in out_names]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        ["case", "status", "seed", *[f"in.{k}" for k in in_names]]
        + [f"out.{k}" for k in out_names]
        + ["check"]
    )
    for c in cases:
        row = [str(c.case), c.status, "" if c.seed is None else str(c.seed)]
        row += [json.dumps(_plain(c.inputs[k])) if k in c.inputs else "" for k in in_names]
        row += [json.dumps(_plain(c.outputs[k])) if k in c.outputs else "" for k in out_names]
        w.writerow([*row, case_check(c)])
    return buf.getvalue()


def write_cases(path: str | os.PathLike, cases: Iterable[Case]) -> Path:
    """Write ``cases`` to ``path`` (``.jsonl`` or ``.csv``) atomically; returns the path."""
    path = Path(path)
    _atomic_write(path, cases_text(cases, _fmt(path)))
    return path


def read_cases(path: str | os.PathLike) -> list[Case]:
    """Read a case file written by :func:`write_cases` / :class:`CaseRecorder`.

    Raises :class:`~encdesign.EncdesignInputError` naming the file and line on bad content.
    """
    path = Path(path)
    fmt = _fmt(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise input_error(str(path), f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise input_error(
            str(path), f"not a text file (byte {exc.start} is not UTF-8)", "a case file"
        ) from None
    if "\x00" in text:
        raise input_error(str(path), "not a text file (NUL bytes)", "a case file")
    out: list[Case] = []
    if fmt == ".jsonl":
        for lineno, line in enumerate(text.splitlines(), start=1):
            if not line.strip():
                continue
            try:
                d = json.loads(line)
                out.append(
                    Case(
                        int(d["case"]),
                        {k: _restore(v) for k, v in d["inputs"].items()},
                        {k: _restore(v) for k, v in d["outputs"].items()},
                        str(d["status"]),
                        None if d.get("seed") is None else int(d["seed"]),
                        None if d.get("check") is None else str(d["check"]),
                    )
                )
            except (ValueError, KeyError, TypeError, AttributeError) as exc:
                raise input_error(
                    f"{path}:{lineno}", f"bad case record ({exc})", "a JSON case object"
                ) from None
        return out
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        return out
    header = rows[0]
    if header[:3] != ["case", "status", "seed"]:
        raise input_error(f"{path}:1", f"bad header {header[:3]}", "case,status,seed,…")
    for lineno, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise input_error(f"{path}:{lineno}", f"{len(row)} cells", f"{len(header)} cells")
        try:
            inputs, outputs, check = {}, {}, None
            for name, cell in zip(header[3:], row[3:]):
                if name == "check":
                    check = cell or None
                    continue
                if cell == "":
                    continue
                val = _restore(json.loads(cell))
                if name.startswith("in."):
                    inputs[name[3:]] = val
                elif name.startswith("out."):
                    outputs[name[4:]] = val
                else:
                    raise EncdesignInputError(f"column {name!r} is neither in.* nor out.*")
            seed = int(row[2]) if row[2] else None
            out.append(Case(int(row[0]), inputs, outputs, row[1], seed, check))
        except ValueError as exc:
            raise input_error(f"{path}:{lineno}", f"bad case row ({exc})") from None
    return out


def case_key(inputs: Mapping[str, object], seed: int | None) -> str:
    """The identity of a case for ``--resume``: its inputs (as recorded, names sorted) and
    its seed. Recorded floats round-trip exactly, so a recomputed design point matches."""
    plain = {str(k): _plain(_restore(_plain(v))) for k, v in inputs.items()}
    return json.dumps({"inputs": plain, "seed": seed}, sort_keys=True, allow_nan=False)


def verify_case(c: Case, path: str | os.PathLike, problem: Problem | None = None) -> None:
    """Refuse a case read for ``--resume`` that cannot be trusted.

    Its checksum (:func:`case_check`) must match the line, its inputs must be finite and,
    with ``problem``, inside the bounds of the problem's continuous variables (SI).

    Raises:
        EncdesignInputError: naming the file, the case and what failed.
    """
    where = f"{path}: case {c.case}"
    if c.check is None:
        raise input_error(where, "has no checksum", "a case file written by this encdesign")
    if c.check != case_check(c):
        raise input_error(
            where, "checksum does not match its values (edited or corrupted)", "the file as written"
        )
    bounds = {}
    if problem is not None:
        bounds = {v.name: (v.lower, v.upper) for v in getattr(problem, "continuous", ())}
    for k, v in c.inputs.items():
        vals = np.asarray(v, dtype=object).reshape(-1)
        for x in vals:
            if isinstance(x, bool) or not isinstance(x, int | float):
                continue
            if not math.isfinite(x):
                raise input_error(f"{where}: inputs.{k}", f"{x!r} is not finite", "finite inputs")
            if k in bounds and not bounds[k][0] <= x <= bounds[k][1]:
                raise input_error(
                    f"{where}: inputs.{k}",
                    f"{x!r} outside the problem's bounds [{bounds[k][0]}, {bounds[k][1]}] (SI)",
                    "a case of this problem",
                )


def part_path(path: str | os.PathLike, process: int) -> Path:
    """The shard file of process ``process`` beside the case file ``path``
    (``cases.jsonl`` -> ``.cases.part-1.jsonl``): the cases that process evaluated so far,
    rewritten atomically after every chunk."""
    p = Path(path)
    return p.with_name(f".{p.stem}.part-{int(process)}{p.suffix}")


def _part_files(path: Path) -> list[Path]:
    return sorted(path.parent.glob(f".{path.stem}.part-*{path.suffix}"))


class CaseRecorder:
    """Collects cases and writes them to ``path`` (atomically, every ``flush_every`` cases
    and on :meth:`close`). Use as a context manager.

    ``path=None`` keeps the cases in memory only (``recorder.cases``).

    With ``resume=True`` the cases already in ``path`` (and in shard files left by an
    interrupted distributed run, :func:`part_path`) are read first; :meth:`lookup` finds
    one by inputs and seed, so a driver can skip it and :meth:`record` it again with its
    recorded outputs. Until the run has recorded them again, the earlier cases stay in the
    file after the new ones, so an interrupted resume loses nothing.

    Under a distributed run every process records the same cases (the drivers gather the
    outputs), but only the process with ``write=True`` (process 0) writes ``path``; each
    process keeps its own shard file of the cases it evaluated (:meth:`record_part`),
    removed when the run closes cleanly.
    """

    def __init__(
        self,
        path: str | os.PathLike | None,
        flush_every: int = 100,
        *,
        resume: bool = False,
        write: bool = True,
        process: int = 0,
        problem: Problem | None = None,
    ):
        self.path = None if path is None else Path(path)
        if self.path is not None:
            _fmt(self.path)
        self.flush_every = int(flush_every)
        self.write = bool(write)
        self.process = int(process)
        self.cases: list[Case] = []
        self.previous: dict[str, Case] = {}
        self._reused: set[str] = set()
        self._part: list[Case] = []
        if resume and self.path is not None:
            files = [self.path] if self.path.exists() else []
            for f in files + _part_files(self.path):
                for c in read_cases(f):
                    verify_case(c, f, problem)
                    self.previous.setdefault(case_key(c.inputs, c.seed), c)

    @property
    def n_reused(self) -> int:
        """Cases recorded again from the earlier file (``resume``)."""
        return len(self._reused)

    def lookup(self, inputs: Mapping[str, object], seed: int | None) -> Case | None:
        """The recorded case with these inputs and seed (``resume``), else ``None``."""
        return self.previous.get(case_key(inputs, seed))

    def record(
        self,
        inputs: Mapping[str, object],
        outputs: Mapping[str, object],
        status: str,
        seed: int | None = None,
    ) -> Case:
        """Append one case (values converted to plain Python numbers) and return it."""
        c = Case(
            len(self.cases),
            {k: _restore(_plain(v)) for k, v in inputs.items()},
            {k: _restore(_plain(v)) for k, v in outputs.items()},
            str(status),
            None if seed is None else int(seed),
        )
        self.cases.append(c)
        k = case_key(c.inputs, c.seed)
        if k in self.previous:
            self._reused.add(k)
        if self.path is not None and len(self.cases) % self.flush_every == 0:
            self.flush()
        return c

    def record_part(
        self,
        cases: Iterable[tuple[Mapping[str, object], Mapping[str, object], str, int | None]],
    ):
        """Add ``(inputs, outputs, status, seed)`` evaluated by this process to its shard
        file (rewritten atomically)."""
        for inputs, outputs, status, seed in cases:
            self._part.append(
                Case(
                    len(self._part),
                    {k: _restore(_plain(v)) for k, v in inputs.items()},
                    {k: _restore(_plain(v)) for k, v in outputs.items()},
                    str(status),
                    None if seed is None else int(seed),
                )
            )
        if self.path is not None:
            write_cases(part_path(self.path, self.process), self._part)

    def all_cases(self) -> list[Case]:
        """What :meth:`flush` writes: the cases recorded, then (``resume``) the earlier
        cases not recorded again."""
        rest = [c for k, c in self.previous.items() if k not in self._reused]
        n = len(self.cases)
        return self.cases + [dataclasses.replace(c, case=n + i) for i, c in enumerate(rest)]

    def flush(self) -> None:
        """Write all cases so far (atomic replace; process 0 only)."""
        if self.path is not None and self.write:
            write_cases(self.path, self.all_cases())

    def close(self) -> None:
        """Flush, then (all processes done) remove this process's shard file."""
        self.flush()
        from .._distributed import barrier

        barrier("encdesign-cases-closed")
        if self.path is not None:
            # process 0 may remove every shard at once: missing here is not an error
            part_path(self.path, self.process).unlink(missing_ok=True)
            if self.write:  # shards left by an interrupted run are now merged
                for f in _part_files(self.path):
                    f.unlink(missing_ok=True)

    def __enter__(self) -> CaseRecorder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self.close()
        elif issubclass(exc_type, EncdesignInputError):
            # a refusal (bad input) leaves no case file behind
            return
        else:  # any other failure keeps what was recorded (and the shard files) for --resume
            self.flush()
