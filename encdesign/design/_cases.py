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
import io
import json
import math
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import EncdesignInputError, input_error
from ..io._paths import atomic_write_text

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


def _plain(x: Any) -> Any:
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


def _restore(x: Any) -> Any:
    if x is None:
        return math.nan
    if isinstance(x, list):
        return [_restore(v) for v in x]
    return x


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
        ["case", "status", "seed", *[f"in.{k}" for k in in_names]] + [f"out.{k}" for k in out_names]
    )
    for c in cases:
        row = [str(c.case), c.status, "" if c.seed is None else str(c.seed)]
        row += [json.dumps(_plain(c.inputs[k])) if k in c.inputs else "" for k in in_names]
        row += [json.dumps(_plain(c.outputs[k])) if k in c.outputs else "" for k in out_names]
        w.writerow(row)
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
            inputs, outputs = {}, {}
            for name, cell in zip(header[3:], row[3:]):
                if cell == "":
                    continue
                val = _restore(json.loads(cell))
                if name.startswith("in."):
                    inputs[name[3:]] = val
                elif name.startswith("out."):
                    outputs[name[4:]] = val
                else:
                    raise ValueError(f"column {name!r} is neither in.* nor out.*")
            out.append(Case(int(row[0]), inputs, outputs, row[1], int(row[2]) if row[2] else None))
        except ValueError as exc:
            raise input_error(f"{path}:{lineno}", f"bad case row ({exc})") from None
    return out


class CaseRecorder:
    """Collects cases and writes them to ``path`` (atomically, every ``flush_every`` cases
    and on :meth:`close`). Use as a context manager.

    ``path=None`` keeps the cases in memory only (``recorder.cases``).
    """

    def __init__(self, path: str | os.PathLike | None, flush_every: int = 100):
        self.path = None if path is None else Path(path)
        if self.path is not None:
            _fmt(self.path)
        self.flush_every = int(flush_every)
        self.cases: list[Case] = []

    def record(
        self,
        inputs: Mapping[str, Any],
        outputs: Mapping[str, Any],
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
        if self.path is not None and len(self.cases) % self.flush_every == 0:
            self.flush()
        return c

    def flush(self) -> None:
        """Write all cases so far (atomic replace)."""
        if self.path is not None:
            write_cases(self.path, self.cases)

    def close(self) -> None:
        """Flush and finish."""
        self.flush()

    def __enter__(self) -> CaseRecorder:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        # a refusal (bad input) leaves no case file behind; any other failure keeps the
        # cases recorded so far
        if exc_type is not None and issubclass(exc_type, EncdesignInputError):
            return
        self.close()
