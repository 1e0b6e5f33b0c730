"""The recording format core: round trips and refusals for every kind."""

import gzip

import numpy as np
import pytest

from encdesign import EncdesignInputError, load_recording, write_recording


def _multihead(tmp_path, **kw):
    t = np.linspace(0.0, 1.0, 50)
    cols = {"t": t, "h0": t * 2, "h1": t * 2 + 0.1, "h2": t * 2 + 0.2}
    cols.update(kw.pop("cols", {}))
    return write_recording(
        tmp_path / "rec.toml",
        "multihead",
        cols,
        encoder={"optical_radius_m": 0.0254, "head_angles_deg": [0.0, 120.0, 240.0]},
        **kw,
    )


def test_multihead_round_trip(tmp_path):
    rec = _multihead(tmp_path, description="bench")
    back = load_recording(tmp_path / "rec.toml")
    assert back.kind == "multihead"
    assert back.head_columns == ["h0", "h1", "h2"]
    np.testing.assert_array_equal(back.heads(), rec.heads())
    assert back.meta["description"] == "bench"


def test_gzip_table(tmp_path):
    t = np.linspace(0.0, 1.0, 20)
    write_recording(
        tmp_path / "q.toml", "quadrature", {"t": t, "sa": np.cos(t), "sb": np.sin(t)}, compress=True
    )
    with gzip.open(tmp_path / "q.csv.gz", "rt") as fh:
        assert fh.readline().strip() == "t,sa,sb"
    assert load_recording(tmp_path / "q.toml").n_rows == 20


def test_motion_counts(tmp_path):
    t = np.linspace(0.0, 1.0, 20)
    rec = write_recording(
        tmp_path / "m.toml",
        "motion",
        {"t": t, "counts": t * 8192},
        encoder={"counts_per_rev": 8192},
        motor={"pole_pairs": 7, "stator_slots": 12},
    )
    assert rec.meta["motor"]["pole_pairs"] == 7


def _write(tmp_path, toml, csv):
    (tmp_path / "r.toml").write_text(toml)
    (tmp_path / "r.csv").write_text(csv)
    return tmp_path / "r.toml"


HEAD = 'format = "encdesign-recording/1"\nkind = "multihead"\ndata = "r.csv"\n'
ENC = "[encoder]\noptical_radius_m = 0.0254\nhead_angles_deg = [0.0, 180.0]\n"


@pytest.mark.parametrize(
    ("toml", "csv", "message"),
    [
        (HEAD + ENC, "t,h0\n0,0\n1,1\n", "missing column(s) h1"),
        (HEAD + ENC, "t,h0,h1,h2\n0,0,0,0\n1,1,1,1\n", "unknown column(s) h2"),
        (HEAD + ENC, "t,h0,h1\n0,0,nan\n1,1,1\n", "line 2, column 'h1'"),
        (HEAD + ENC, "t,h0,h1\n0,0,0\n1,1,abc\n", "line 3, column 'h1'"),
        (HEAD + ENC, "t,h0,h1\n1,0,0\n0,1,1\n", "time goes backwards"),
        (HEAD + ENC + "colour = 3\n", "t,h0,h1\n0,0,0\n", "unknown key(s) colour"),
        (HEAD + "extra = 1\n" + ENC, "t,h0,h1\n0,0,0\n", "unknown key(s) extra"),
        (HEAD.replace("multihead", "hologram") + ENC, "t\n0\n", "kind"),
        (HEAD.replace("/1", "/9") + ENC, "t\n0\n", "format"),
        (HEAD + ENC.replace("0.0254", "-1.0"), "t,h0,h1\n0,0,0\n", "positive"),
        (HEAD + ENC, "t,h0,h1\n0,0\n", "2 fields"),
        (HEAD + ENC, "t,h0,h1\n", "no rows"),
    ],
)
def test_refusals_name_the_problem(tmp_path, toml, csv, message):
    path = _write(tmp_path, toml, csv)
    before = (tmp_path / "r.csv").read_bytes()
    with pytest.raises(EncdesignInputError) as info:
        load_recording(path)
    assert message in str(info.value)
    assert str(tmp_path) in str(info.value)
    assert (tmp_path / "r.csv").read_bytes() == before  # never modified


def test_missing_data_file(tmp_path):
    (tmp_path / "r.toml").write_text(HEAD + ENC)
    with pytest.raises(EncdesignInputError, match="not found"):
        load_recording(tmp_path / "r.toml")


def test_write_refuses_without_leaving_files(tmp_path):
    with pytest.raises(EncdesignInputError):
        _multihead(tmp_path, cols={"h1": np.array([np.nan] * 50)})
    assert list(tmp_path.iterdir()) == []
