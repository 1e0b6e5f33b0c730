"""Output-path checks and atomic writes (encdesign.io._paths, issue 12)."""

from __future__ import annotations

import os

import pytest

from encdesign._errors import EncdesignInputError
from encdesign.io._paths import (
    OutputGuard,
    atomic_output,
    atomic_write_text,
    check_output_folder,
    check_outputs,
    recording_input_files,
    recording_output_files,
)


def test_atomic_write_has_normal_permissions_and_replaces_whole(tmp_path):
    p = tmp_path / "a" / "b.txt"
    old = os.umask(0o022)
    try:
        atomic_write_text(p, "one")
    finally:
        os.umask(old)
    assert p.read_text() == "one"
    assert p.stat().st_mode & 0o777 == 0o644
    with pytest.raises(RuntimeError), atomic_output(p) as fh:
        fh.write("half")
        raise RuntimeError("disk full")
    assert p.read_text() == "one"
    assert sorted(x.name for x in p.parent.iterdir()) == ["b.txt"]


@pytest.mark.parametrize("compress", [False, True])
def test_recording_files_derive_the_table(tmp_path, compress):
    toml, table = recording_output_files(tmp_path / "r.toml", compress=compress)
    assert table.name == ("r.csv.gz" if compress else "r.csv")
    with pytest.raises(EncdesignInputError, match="NAME.toml"):
        recording_output_files(tmp_path / "r.csv")
    toml.write_text('data = "sub/t.csv"\n')
    assert recording_input_files(toml) == [toml, tmp_path / "sub/t.csv"]
    toml.write_bytes(b"\x00 not toml")
    assert recording_input_files(toml) == [toml]


def test_clashes_by_path_link_and_between_outputs(tmp_path):
    src = tmp_path / "in.toml"
    src.write_text("x = 1\n")
    (tmp_path / "soft").symlink_to(src)
    os.link(src, tmp_path / "hard")
    for out in (src, tmp_path / "soft", tmp_path / "hard", tmp_path / "." / "in.toml"):
        with pytest.raises(EncdesignInputError, match="is the input"):
            check_outputs([("in", src)], [("--json", out)])
    with pytest.raises(EncdesignInputError, match="is also the output"):
        check_outputs([], [("--json", tmp_path / "o"), ("--report", tmp_path / "o")])
    check_outputs([("in", src)], [("--json", tmp_path / "new" / "o.json")])


def test_unwritable_outputs_refused(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "f").write_text("")
    ro = tmp_path / "ro"
    ro.write_text("")
    ro.chmod(0o444)
    cases = {
        tmp_path / "d": "folder",
        tmp_path / "f" / "x.json": "not a folder",
        ro: "read-only",
        tmp_path / "..": "not a file name",
    }
    for out, needle in cases.items():
        with pytest.raises(EncdesignInputError, match=needle):
            check_outputs([], [("--json", out)])
    with pytest.raises(EncdesignInputError, match="not a folder"):
        check_output_folder("--plots", tmp_path / "f")
    with pytest.raises(EncdesignInputError, match="cannot be written"):
        check_outputs([], [("--json", "/proc/encdesign-test.json")])


def test_guard_removes_only_what_the_failed_command_created(tmp_path):
    keep = tmp_path / "keep.json"
    keep.write_text("old")
    new = tmp_path / "n1" / "n2" / "new.json"
    with pytest.raises(RuntimeError), OutputGuard([keep, new], [tmp_path / "plots"]):
        atomic_write_text(keep, "replaced")
        atomic_write_text(new, "x")
        atomic_write_text(tmp_path / "plots" / "a.png", "png")
        raise RuntimeError
    assert keep.read_text() == "replaced"  # existed: replaced atomically, never removed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.json"]
    with OutputGuard([new]):
        atomic_write_text(new, "ok")
    assert new.read_text() == "ok"
