import subprocess
import sys

from encdesign.cli._main import available_studies, main


def test_help_lists_study_command(capsys):
    assert main([]) == 2
    assert "study" in capsys.readouterr().out


def test_unknown_command_exits_2(capsys):
    assert main(["no-such-command"]) == 2
    assert "unknown command" in capsys.readouterr().err


def test_unknown_study_exits_2(capsys):
    assert main(["study", "run", "no-such-study"]) == 2
    assert "unknown" in capsys.readouterr().err


def test_console_script_runs():
    out = subprocess.run(
        [sys.executable, "-m", "encdesign.cli", "study", "list"],
        capture_output=True,
        text=True,
        check=True,
    )
    names = set(available_studies())
    for name in names:
        assert name in out.stdout


def test_version_flag(capsys):
    from importlib.metadata import version

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"encdesign {version('encdesign')}"


def test_every_command_module_is_discovered():
    """Each ``encdesign/cli/_<name>.py`` but the entry point itself is a sub-command."""
    from pathlib import Path

    import encdesign.cli
    from encdesign.cli._main import _command_modules

    cli = Path(encdesign.cli.__file__).parent
    files = {f.stem[1:].replace("_", "-") for f in cli.glob("_*.py") if not f.stem.startswith("__")}
    assert set(_command_modules()) == files - {"main"}
    assert {"diagnose", "optimize", "simulate", "import"} <= set(_command_modules())


def test_study_reports_each_output_once(tmp_path, capsys):
    """``--json`` equal to ``OUT/<name>.json`` (as ``make demo`` passes) is written once."""
    out = tmp_path / "cramer"
    rc = main(
        ["study", "run", "cramer", "--quick", "--out", str(out), "--json", str(out / "cramer.json")]
    )
    assert rc == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("wrote ")]
    assert len(lines) == len(set(lines))
    assert sum(ln.endswith("cramer.json") for ln in lines) == 1


def test_progress_bar_is_tqdm_and_quiet_off_a_terminal(capsys):
    import io

    from tqdm import tqdm

    from encdesign._progress import progress_bar

    buf = io.StringIO()  # not a terminal: tqdm's disable=None keeps it silent
    with progress_bar("work", 5, stream=buf) as bar:
        assert isinstance(bar, tqdm)
        bar.update(5)
    assert buf.getvalue() == ""
    with progress_bar("work", 5, enabled=False) as bar:
        bar.update(5)
    assert capsys.readouterr().err == ""
