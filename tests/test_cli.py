import subprocess
import sys

from encdesign._cli import available_studies, main


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
        [sys.executable, "-m", "encdesign._cli", "study", "list"],
        capture_output=True,
        text=True,
        check=True,
    )
    names = set(available_studies())
    for name in names:
        assert name in out.stdout
