"""Shared plumbing for ``studies/*.py``: flags, output folder, JSON and PNG writing.

Every study has a title docstring, a ``main(argv=None) -> int``, flags made by
:func:`study_parser`, and ends with :func:`write_results`, which writes
``OUT/<name>.json`` (and the ``--json`` file if given) and returns the paths.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._checks import SEED, float_arg, int_arg
from .._errors import EncdesignInputError
from ._paths import atomic_output, atomic_write_text

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "float_arg",
    "int_arg",
    "new_figure",
    "save_figure",
    "study_parser",
    "to_jsonable",
    "write_json",
    "write_results",
]


class _OneLineParser(argparse.ArgumentParser):
    """Usage errors as one line on stderr and exit status 2 (the CLI's contract)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


MAX_COUNT = 10_000_000
"""Largest value of a study's plain integer flag (counts: marks, samples, trials …)."""
MAX_NUMBER = 1e6
"""Largest magnitude of a study's plain number flag (in the flag's unit)."""


class _StudyParser(_OneLineParser):
    """A study's parser: after parsing, every output is checked before the study computes.

    ``--out`` must be a folder that can be created or written, ``--json`` and
    ``OUT/<name>.json`` files that can be written and are none of the study's input files
    (its other ``Path`` flags); a refusal is exit 2 naming the flag, with nothing written.
    """

    study_name: str = ""

    def add_argument(self, *args, **kwargs):  # type: ignore[override]
        """A plain ``type=int`` becomes a count ``1 … MAX_COUNT``, a plain ``type=float`` a
        finite number ``-MAX_NUMBER … MAX_NUMBER``; studies give narrower documented
        ranges with :func:`int_arg` / :func:`float_arg` themselves."""
        if kwargs.get("type") is int:
            kwargs["type"] = int_arg(1, MAX_COUNT)
        elif kwargs.get("type") is float:
            kwargs["type"] = float_arg(-MAX_NUMBER, MAX_NUMBER)
        return super().add_argument(*args, **kwargs)

    def parse_args(self, args=None, namespace=None):  # type: ignore[override]
        ns = super().parse_args(args, namespace)
        from .._errors import EncdesignInputError
        from ._paths import check_output_folder, check_outputs

        inputs = [
            (f"--{a.dest.replace('_', '-')}", getattr(ns, a.dest))
            for a in self._actions
            if a.type is Path and a.dest not in ("out", "json") and getattr(ns, a.dest, None)
        ]
        inputs = [(lab, p) for lab, p in inputs if Path(p).is_file()]
        outs = [("--out", Path(ns.out) / f"{self.study_name}.json")]
        if ns.json is not None:
            outs.append(("--json", Path(ns.json)))
        try:
            check_output_folder("--out", ns.out, inputs)
            if ns.json is not None and _same(Path(ns.json), outs[0][1]):
                outs.pop()  # the --json copy is OUT/<name>.json: written once
            check_outputs(inputs, outs)
        except EncdesignInputError as exc:
            self.error(str(exc))
        return ns


def _same(a: Path, b: Path) -> bool:
    return os.path.realpath(a) == os.path.realpath(b)


def study_parser(name: str, doc: str | None) -> argparse.ArgumentParser:
    """An argument parser with the flags every study has.

    ``--out DIR`` (default ``results/<name>``), ``--json FILE`` (summary also written
    there), ``--seed N`` (PRNG seed, default 0), ``--quick`` (smaller sizes for tests).
    The outputs are checked when the arguments are parsed, before the study computes.
    Studies give their numeric flags checked types (:func:`int_arg`, :func:`float_arg`,
    re-exported here) with their documented range.
    """
    title = (doc or name).strip().splitlines()[0]
    p = _StudyParser(prog=f"encdesign study run {name}", description=title)
    p.study_name = name
    p.add_argument("--out", type=Path, default=Path("results") / name, help="output folder")
    p.add_argument("--json", type=Path, default=None, help="also write the summary JSON here")
    p.add_argument("--seed", type=SEED, default=0, help="PRNG seed, 0 … 2^63-1 (default 0)")
    p.add_argument("--quick", action="store_true", help="smaller sizes (for tests)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    return p


def to_jsonable(x: Any) -> Any:
    """Convert numpy/JAX scalars and arrays (recursively) to plain JSON types.

    Non-finite floats raise ``ValueError``: a study never writes a silent NaN.
    """
    if isinstance(x, Mapping):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [to_jsonable(v) for v in x]
    if hasattr(x, "__array__") and not isinstance(x, str | bytes):
        arr = np.asarray(x)
        if arr.ndim == 0:
            return to_jsonable(arr.item())
        return [to_jsonable(v) for v in arr.tolist()]
    if isinstance(x, float):
        if not math.isfinite(x):
            raise EncdesignInputError(f"non-finite value {x!r} in study results")
        return x
    if isinstance(x, np.generic):
        return to_jsonable(x.item())
    return x


def write_json(path: str | os.PathLike, data: Mapping[str, Any]) -> Path:
    """Write ``data`` as indented JSON atomically (temporary file renamed into place)."""
    text = json.dumps(to_jsonable(data), indent=2, sort_keys=False)
    return atomic_write_text(path, text + "\n")


def write_results(
    args: argparse.Namespace, name: str, summary: Mapping[str, Any], figures: Sequence[Path] = ()
) -> list[Path]:
    """Write ``OUT/<name>.json`` and the ``--json`` copy; print each path written once.

    A ``--json`` path that resolves to ``OUT/<name>.json`` (as in ``make demo``) is written
    and reported once, not twice."""
    targets = [Path(args.out) / f"{name}.json"]
    if args.json is not None:
        targets.append(Path(args.json))
    paths: list[Path] = []
    seen: set[Path] = set()
    for t in targets:
        key = t.resolve()
        if key in seen:
            continue
        seen.add(key)
        paths.append(write_json(t, summary))
    for p in [*paths, *figures]:
        print(f"wrote {p}")
    return paths


def new_figure(*args: Any, **kwargs: Any):
    """``plt.subplots`` on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


def save_figure(fig: Figure, out: str | os.PathLike, filename: str) -> Path:
    """Save a matplotlib figure as PNG under ``out`` and close it."""
    import matplotlib.pyplot as plt

    out = Path(out)
    path = out / filename
    fig.tight_layout()
    try:
        with atomic_output(path, "wb") as fh:
            fig.savefig(fh, dpi=120, format="png")
    finally:
        plt.close(fig)
    return path
