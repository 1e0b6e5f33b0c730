"""The ``encdesign`` command line: one entry point, thin over the library.

Sub-commands are discovered from the private modules ``encdesign/cli/_<name>.py`` (dashes
in ``<name>`` written as underscores; ``_main`` is this module). Each defines ``HELP`` (one
line), ``configure(parser)`` and ``run(args) -> int``. ``study`` is built in:
``encdesign study list`` and ``encdesign study run NAME [study flags]`` run
``studies/NAME.py``'s ``main(argv)``.

Bad input (:class:`~encdesign.EncdesignInputError`) becomes one line on stderr and exit
status 2.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from collections.abc import Sequence
from pathlib import Path

from .._errors import EncdesignInputError

_CLI = Path(__file__).resolve().parent
_PKG = _CLI.parent


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
    p = argparse.ArgumentParser(prog="encdesign study", description="Run reproducible studies.")
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
    from ..design import _distributed as dist

    launch_p = argparse.ArgumentParser(prog=f"encdesign study run {args.name}", add_help=False)
    dist.add_launch_flags(launch_p)
    launch, flags = launch_p.parse_known_args(list(args.flags))
    argv = ["study", "run", args.name, *flags]
    if launch.processes is not None:
        argv += ["--processes", str(launch.processes)]

    def body() -> int:
        with dist.quiet_unless_main():
            return int(mod.main(dist.study_argv_for_this_process(args.name, flags)) or 0)

    return dist.run_launched(launch, argv, body)


def _version() -> str:
    """The installed distribution's version (``pyproject.toml``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("encdesign")
    except PackageNotFoundError:  # pragma: no cover - running from a bare source tree
        return "unknown (not installed)"


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status (0 ok, 2 bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] in (["--version"], ["-V"]):
        print(f"encdesign {_version()}")
        return 0
    commands = _command_modules()
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: encdesign [--version] COMMAND [...]\n\ncommands:")
        print(f"  {'study':16s} run or list the reproducible studies (studies/*.py)")
        for name, modname in commands.items():
            mod = importlib.import_module(modname)
            print(f"  {name:16s} {getattr(mod, 'HELP', '')}")
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    try:
        if cmd == "study":
            return _run_study(rest)
        if cmd not in commands:
            print(
                f"encdesign: unknown command '{cmd}' "
                f"(expected one of study, {', '.join(commands)})",
                file=sys.stderr,
            )
            return 2
        mod = importlib.import_module(commands[cmd])
        parser = argparse.ArgumentParser(prog=f"encdesign {cmd}", description=mod.HELP)
        mod.configure(parser)
        args = parser.parse_args(rest)
        args.command_argv = [cmd, *rest]  # to re-run the command (--processes N)
        return int(mod.run(args) or 0)
    except EncdesignInputError as exc:
        print(f"encdesign {cmd}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
