"""The ``encdesign`` command line: one entry point, thin over the library.

Sub-commands are discovered from the private modules ``encdesign/cli/_<name>.py`` (dashes
in ``<name>`` written as underscores; ``_main`` is this module). Each defines ``HELP`` (one
line), ``configure(parser)`` and ``run(args) -> int``. ``study`` is built in:
``encdesign study list`` and ``encdesign study run NAME [study flags]`` run
``studies/NAME.py``'s ``main(argv)``.

Shared by the commands: checked argument types (:func:`int_arg`, :func:`float_arg`,
:data:`SEED`) that refuse out-of-range, non-finite and absurd values while arguments are
parsed, and :func:`guard_outputs`, which checks every output path against the command's
inputs and other outputs (by path and resolved identity, :mod:`encdesign.io._paths`)
before any work and removes what a failed command created.

Exit status (a contract, see the README): ``0`` success; ``1`` a solve or check that ran
but failed (its status is printed); ``2`` bad input (a usage error or an
:class:`~encdesign.EncdesignInputError`: one line on stderr naming the file, key or flag);
``3`` an internal error (one line saying so; ``--debug`` anywhere on the command line, or
``ENCDESIGN_DEBUG=1``, shows the traceback instead); ``130`` interrupted. No traceback
reaches the user otherwise.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from ..errors import EncdesignInputError
from ..io import (  # noqa: F401 (SEED, SEED_MAX, float_arg, int_arg: used by commands)
    SEED,
    SEED_MAX,
    OutputGuard,
    check_output_folder,
    check_outputs,
    float_arg,
    int_arg,
)

_CLI = Path(__file__).resolve().parent
_PKG = _CLI.parent


# ----------------------------------------------------------------------------- shared by commands


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def guard_outputs(
    inputs: Sequence[tuple[str, str | os.PathLike]],
    outputs: Sequence[tuple[str, str | os.PathLike | None]],
    folders: Sequence[tuple[str, str | os.PathLike | None]] = (),
) -> OutputGuard:
    """Check outputs against inputs (refusing before any work) and guard them.

    Args:
        inputs: ``(label, path)`` of every file read, derived files included.
        outputs: ``(label, path)`` of every file written (``None`` paths are skipped).
        folders: ``(label, path)`` of output folders (``--plots DIR``).

    Returns:
        The guard to use as a context manager around the computation and writing.
    """
    outs = [(lab, p) for lab, p in outputs if p is not None]
    dirs = [(lab, p) for lab, p in folders if p is not None]
    check_outputs(inputs, outs)
    for lab, d in dirs:
        check_output_folder(lab, d, inputs, outs)
    return OutputGuard([p for _, p in outs], [d for _, d in dirs])


# ----------------------------------------------------------------------------- dispatch


def _command_modules() -> dict[str, str]:
    out = {}
    for f in sorted(_CLI.glob("_*.py")):
        if f.stem in ("_main", "__init__", "__main__"):
            continue
        out[f.stem[1:].replace("_", "-")] = f"encdesign.cli.{f.stem}"
    return out


def study_dirs() -> list[Path]:
    """Folders searched for study scripts: the repository's ``studies/``, then the copy
    bundled into an installed wheel."""
    return [p for p in (_PKG.parent / "studies", _PKG / "_bundled_studies") if p.is_dir()]


def available_studies() -> dict[str, Path]:
    """Study name (dashes) -> script path."""
    found: dict[str, Path] = {}
    for d in study_dirs():
        for f in sorted(d.glob("*.py")):
            if f.name.startswith("_"):
                continue
            found.setdefault(f.stem.replace("_", "-"), f)
    return found


def _load_study(name: str):
    studies = available_studies()
    if name not in studies:
        raise EncdesignInputError(
            f"study '{name}': unknown (expected one of {', '.join(sorted(studies)) or 'none'})"
        )
    path = studies[name]
    spec = importlib.util.spec_from_file_location(f"encdesign_study_{path.stem}", path)
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    return mod


def _study_title(path: Path) -> str:
    for line in path.read_text(encoding="utf-8").splitlines():
        s = line.strip().strip('"').strip()
        if s:
            return s
    return ""


def _run_study(argv: Sequence[str]) -> int:
    p = OneLineParser(prog="encdesign study", description="Run reproducible studies.")
    sub = p.add_subparsers(dest="action", required=True)
    sub.add_parser("list", help="list the studies")
    r = sub.add_parser("run", help="run a study: encdesign study run NAME [flags]")
    r.add_argument("name")
    r.add_argument("flags", nargs=argparse.REMAINDER, help="flags passed to the study")
    args = p.parse_args(argv)
    if args.action == "list":
        for name, path in available_studies().items():
            print(f"{name:22s} {_study_title(path)}")
        return 0
    mod = _load_study(args.name)
    from .. import distributed as dist

    launch_p = argparse.ArgumentParser(prog=f"encdesign study run {args.name}", add_help=False)
    dist.add_launch_flags(launch_p)
    launch, flags = launch_p.parse_known_args(list(args.flags))
    argv = ["study", "run", args.name, *flags]
    if launch.processes is not None:
        argv += ["--processes", str(launch.processes)]

    rc = dist.start(launch, argv)
    if rc is not None:  # spawned the processes, or could not join the runtime
        return rc
    with dist.quiet_unless_main():
        rc = int(mod.main(dist.study_argv_for_this_process(args.name, flags)) or 0)
    dist.shutdown()
    return rc


def _version() -> str:
    """The installed distribution's version (``pyproject.toml``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("encdesign")
    except PackageNotFoundError:  # pragma: no cover - running from a bare source tree
        return "unknown (not installed)"


EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
"""Exit statuses of every command (the README states the contract)."""


_NUMPY_REPR = re.compile(r"np\.(?:float|int|uint|complex|bool_|str_)\w*\(([^()]*)\)")


def _one_line(text: object) -> str:
    """A message on one line, NumPy scalar reprs (``np.float64(0.5)``) shown as plain values."""
    return _NUMPY_REPR.sub(r"\1", " ".join(str(text).split()))


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status (0 ok, 1 failed, 2 bad input, 3 internal).

    ``--debug`` (anywhere in ``argv``) or ``ENCDESIGN_DEBUG=1`` lets internal errors raise
    with their traceback instead of the one-line message.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = os.environ.get("ENCDESIGN_DEBUG", "") not in ("", "0")
    if "--debug" in argv:
        debug = True
        argv = [a for a in argv if a != "--debug"]
    if argv[:1] in (["--version"], ["-V"]):
        print(f"encdesign {_version()}")
        return EXIT_OK
    commands = _command_modules()
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: encdesign [--version] [--debug] COMMAND [...]\n\ncommands:")
        print(f"  {'study':16s} run or list the reproducible studies (studies/*.py)")
        for name, modname in commands.items():
            mod = importlib.import_module(modname)
            print(f"  {name:16s} {getattr(mod, 'HELP', '')}")
        return EXIT_OK if argv else EXIT_BAD_INPUT
    cmd, rest = argv[0], argv[1:]
    try:
        if cmd == "study":
            return _run_study(rest)
        if cmd not in commands:
            print(
                f"encdesign: error: unknown command '{cmd}' "
                f"(expected one of study, {', '.join(commands)})",
                file=sys.stderr,
            )
            return EXIT_BAD_INPUT
        mod = importlib.import_module(commands[cmd])
        parser = OneLineParser(prog=f"encdesign {cmd}", description=mod.HELP)
        mod.configure(parser)
        args = parser.parse_args(rest)
        args.command_argv = [cmd, *rest]  # to re-run the command (--processes N)
        return int(mod.run(args) or 0)
    except EncdesignInputError as exc:
        print(f"encdesign {cmd}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2, one line printed)
        code = exc.code
        return code if isinstance(code, int) else (EXIT_OK if code is None else EXIT_BAD_INPUT)
    except KeyboardInterrupt:
        print(f"encdesign {cmd}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except MemoryError:
        if debug:
            raise
        print(
            f"encdesign {cmd}: error: out of memory (internal error; rerun with --debug "
            "for the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL
    except Exception as exc:
        if debug:
            raise
        print(
            f"encdesign {cmd}: internal error: {type(exc).__name__}: {_one_line(exc)[:300]} "
            "(a bug; rerun with --debug for the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
