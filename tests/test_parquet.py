"""Parquet data tables: round trips, refusals naming file, row group and column, and the
same diagnosis from a CSV and a Parquet copy of one record."""

from __future__ import annotations

import hashlib
import json
import re

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from encdesign import EncdesignInputError, load_recording, write_recording
from encdesign.cli import main as cli_main
from encdesign.io import _parquet

TIMES = ("time_s", "timings_s", "timings_cpu_s")
ENC = {"head_angles_deg": [0.0, 120.0, 240.0], "optical_radius_m": 0.0254}
TOML = """format = "encdesign-recording/1"
kind = "multihead"
data = "{data}"
[encoder]
head_angles_deg = [0.0, 120.0, 240.0]
"""


def _columns(seed: int, n: int = 40, runs: int = 2) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.tile(np.arange(n) * 0.01, runs)
    run = np.repeat(np.arange(runs), n)
    th = 2 * np.pi * t + rng.uniform(0, 6, runs)[run]
    cols = {"t": t, "run": run}
    for k in range(3):
        cols[f"h{k}"] = th + 1e-6 * rng.normal(size=t.size) + k
    return cols


def _write_table(tmp_path, table: pa.Table, row_group_size: int = 10):
    pq.write_table(table, tmp_path / "r.parquet", row_group_size=row_group_size)
    (tmp_path / "r.toml").write_text(TOML.format(data="r.parquet"))
    return tmp_path / "r.toml"


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("seed", [3, 11])
def test_round_trip_in_row_groups_is_exact(tmp_path, monkeypatch, seed):
    monkeypatch.setattr(_parquet, "ROW_GROUP_ROWS", 7)
    cols = _columns(seed)
    rec = write_recording(tmp_path / "a.toml", "multihead", cols, encoder=ENC, parquet=True)
    assert rec.meta["data"] == "a.parquet"
    pf = pq.ParquetFile(tmp_path / "a.parquet")
    assert pf.num_row_groups == -(-80 // 7)
    assert str(pf.schema_arrow.field("run").type) == "int64"
    before = _digest(tmp_path / "a.parquet")
    back = load_recording(tmp_path / "a.toml")
    for k, v in cols.items():
        assert back.columns[k].dtype == v.dtype
        np.testing.assert_array_equal(back.columns[k], v)
    assert _digest(tmp_path / "a.parquet") == before  # the input is never modified


def test_float_columns_are_written_plain_and_uncompressed(tmp_path):
    """A float64 reading does not compress, and its decode from ``snappy`` cost twice the CPU
    (issue 43, docs/scale.md): float columns are written plain and uncompressed, the others
    dictionary-encoded and ``snappy``-compressed; a ``snappy`` file is still read."""
    cols = _columns(5)
    write_recording(tmp_path / "a.toml", "multihead", cols, encoder=ENC, parquet=True)
    meta = pq.ParquetFile(tmp_path / "a.parquet").metadata.row_group(0)
    got = {meta.column(i).path_in_schema: meta.column(i) for i in range(meta.num_columns)}
    for name, col in got.items():
        if cols[name].dtype.kind == "f":
            assert col.compression == "UNCOMPRESSED" and "PLAIN_DICTIONARY" not in col.encodings
            assert "RLE_DICTIONARY" not in col.encodings, name
        else:
            assert col.compression == "SNAPPY", name
    pq.write_table(pa.table(cols), tmp_path / "a.parquet", compression="snappy")
    back = load_recording(tmp_path / "a.toml")
    for k, v in cols.items():
        np.testing.assert_array_equal(back.columns[k], v)


def test_data_name_suffix_chooses_parquet_and_gzip_is_refused(tmp_path):
    cols = _columns(1)
    write_recording(tmp_path / "b.toml", "multihead", cols, encoder=ENC, data_name="x.pq")
    assert (tmp_path / "x.pq").read_bytes()[:4] == b"PAR1"
    assert load_recording(tmp_path / "b.toml").n_rows == 80
    with pytest.raises(EncdesignInputError, match="gzip compression asked of a Parquet"):
        write_recording(
            tmp_path / "c.toml", "multihead", cols, encoder=ENC, parquet=True, compress=True
        )
    assert not (tmp_path / "c.toml").exists() and not (tmp_path / "c.parquet").exists()


def test_parquet_content_under_a_csv_name_is_read(tmp_path):
    cols = _columns(2)
    pq.write_table(pa.table(cols), tmp_path / "r.csv")
    (tmp_path / "r.toml").write_text(TOML.format(data="r.csv"))
    np.testing.assert_array_equal(load_recording(tmp_path / "r.toml").columns["h1"], cols["h1"])


def test_sds_string_and_integer_columns(tmp_path):
    cols = {
        "run": np.zeros(6, np.int64),
        "sensor": np.array(["f0", "m0", "f0", "m0", "f0", "m0"]),
        "mark": np.array([0, 0, 1, 1, 2, 2]),
        "t": np.arange(6) * 1e-3,
    }
    enc = {"marks_per_rev": 3, "fixed_sensor_angles_deg": [0.0], "moving_sensor_angles_deg": [0.0]}
    write_recording(tmp_path / "s.toml", "sds", cols, encoder=enc, parquet=True)
    back = load_recording(tmp_path / "s.toml")
    assert back.columns["sensor"].tolist() == cols["sensor"].tolist()
    assert back.columns["mark"].dtype == np.int64


def _bad(tmp_path, cols: dict, match: str, **kw):
    path = _write_table(tmp_path, pa.table(cols), **kw)
    before = _digest(tmp_path / "r.parquet")
    with pytest.raises(EncdesignInputError) as e:
        load_recording(path)
    msg = str(e.value)
    assert msg.startswith(str(tmp_path / "r.parquet")), msg
    assert match in msg, msg
    assert "\n" not in msg
    assert _digest(tmp_path / "r.parquet") == before
    return msg


@pytest.mark.parametrize("seed", [5, 17])
def test_nan_is_located_by_row_group_row_and_column(tmp_path, seed):
    rng = np.random.default_rng(seed)
    cols = _columns(seed)
    i = int(rng.integers(0, 80))
    col = f"h{int(rng.integers(0, 3))}"
    cols[col] = cols[col].copy()
    cols[col][i] = np.nan
    msg = _bad(tmp_path, cols, f"row group {i // 10}, row {i % 10}, column '{col}'")
    assert "non-finite" in msg


def test_time_backwards_is_located(tmp_path):
    cols = _columns(4)
    cols["t"] = cols["t"].copy()
    cols["t"][23] = cols["t"][22]
    msg = _bad(tmp_path, cols, "row group 2, row 3, column 't'")
    assert "row group 2, row 2" in msg  # the row it repeats


def test_wrong_and_missing_columns(tmp_path):
    cols = _columns(6)
    cols["h7"] = cols.pop("h2")
    _bad(tmp_path, cols, "missing column(s) h2")
    cols = _columns(6)
    cols["speed"] = cols["t"]
    _bad(tmp_path, cols, "unknown column(s) speed")


def test_wrong_dtype_null_and_fractional_run(tmp_path):
    cols = _columns(7)
    table = pa.table(cols).set_column(2, "h0", pa.array([str(x) for x in cols["h0"]]))
    _bad_table(tmp_path, table, "column 'h0': Parquet type string")
    table = pa.table(cols).set_column(2, "h0", pa.array(cols["h0"] > 1))
    _bad_table(tmp_path, table, "column 'h0': Parquet type bool")
    h1 = pa.array([None if k == 35 else x for k, x in enumerate(cols["h1"])], pa.float64())
    table = pa.table(cols).set_column(3, "h1", h1)
    _bad_table(tmp_path, table, "row group 3, row 5, column 'h1': an empty (null) cell")
    run = cols["run"].astype(float)
    run[52] = 1.5
    table = pa.table({**cols, "run": run})
    _bad_table(tmp_path, table, "row group 5, row 2, column 'run': got 1.5")


def _bad_table(tmp_path, table, match):
    path = _write_table(tmp_path, table)
    with pytest.raises(EncdesignInputError) as e:
        load_recording(path)
    assert str(e.value).startswith(str(tmp_path / "r.parquet")) and match in str(e.value), str(
        e.value
    )


def test_missing_truncated_and_not_parquet_files(tmp_path):
    (tmp_path / "r.toml").write_text(TOML.format(data="r.parquet"))
    with pytest.raises(EncdesignInputError, match="r.parquet: data file not found"):
        load_recording(tmp_path / "r.toml")
    _write_table(tmp_path, pa.table(_columns(8)))
    whole = (tmp_path / "r.parquet").read_bytes()
    for cut in (len(whole) // 2, len(whole) - 3, 10):
        (tmp_path / "r.parquet").write_bytes(whole[:cut])
        with pytest.raises(EncdesignInputError, match="truncated or corrupt") as e:
            load_recording(tmp_path / "r.toml")
        assert str(e.value).startswith(str(tmp_path / "r.parquet"))
        assert (tmp_path / "r.parquet").read_bytes() == whole[:cut]
    (tmp_path / "r.parquet").write_text("t,h0,h1,h2\n0,0,0,0\n")
    with pytest.raises(EncdesignInputError, match="not a readable Parquet file"):
        load_recording(tmp_path / "r.toml")


def test_corrupt_row_group_is_named(tmp_path):
    """Garbage over the data pages of one row group (uncompressed, so the page headers
    break): the message names that row group, or the file when the footer is hit."""
    cols = _columns(9, n=200)
    pq.write_table(pa.table(cols), tmp_path / "r.parquet", row_group_size=100, compression="none")
    (tmp_path / "r.toml").write_text(TOML.format(data="r.parquet"))
    md = pq.ParquetFile(tmp_path / "r.parquet").metadata
    rg = md.row_group(2)
    start = rg.column(0).data_page_offset
    blob = bytearray((tmp_path / "r.parquet").read_bytes())
    blob[start : start + 64] = b"\xff" * 64
    (tmp_path / "r.parquet").write_bytes(bytes(blob))
    with pytest.raises(EncdesignInputError) as e:
        load_recording(tmp_path / "r.toml")
    assert "r.parquet, row group 2: cannot be decoded" in str(e.value), str(e.value)


def _bench_columns(seed: int) -> dict[str, np.ndarray]:
    """Two runs of 600 rows at 200 Hz, 3 heads, disk errors of orders 1-4, 0.5 urad noise
    and per-run zeros; with a 37 Hz vibration (seed odd) or none (seed even)."""
    rng = np.random.default_rng(seed)
    noise = 5e-7
    alpha = np.radians(ENC["head_angles_deg"])
    n, R = 600, 2
    t = np.tile(np.arange(n) / 200.0, R)
    run = np.repeat(np.arange(R), n)
    th = 2 * np.pi * (1.0 + 0.6 * run) * t + rng.uniform(0, 6, R)[run]
    err = np.zeros((t.size, 3))
    for m in range(1, 5):
        err += 8 * noise / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6))
    if seed % 2:
        err += 3 * noise * np.sin(2 * np.pi * 37.0 * t[:, None] + rng.uniform(0, 6, (R, 3))[run])
    read = th[:, None] + err + rng.normal(0, noise, err.shape)
    read += (rng.integers(-3, 4, (R, 3)) * 2 * np.pi + rng.uniform(-3, 3, (R, 3)))[run]
    cols = {"t": t, "run": run, "theta_ref": th}
    cols.update({f"h{k}": read[:, k] for k in range(3)})
    return cols


@pytest.mark.parametrize("seed", [21, 34])
def test_csv_and_parquet_diagnose_identically(tmp_path, seed):
    cols = _bench_columns(seed)
    for name, kw in (("c", {}), ("p", {"parquet": True})):
        write_recording(tmp_path / f"{name}.toml", "multihead", cols, encoder=ENC, **kw)
    before = _digest(tmp_path / "p.parquet")
    docs = []
    for name in ("c", "p"):
        out = tmp_path / f"{name}.json"
        args = ["diagnose", str(tmp_path / f"{name}.toml"), "--json", str(out), "--quiet"]
        assert cli_main(args) == 0
        text = out.read_text().replace(str(tmp_path / f"{name}.toml"), "REC")
        text = re.sub(r"status: (\w+); [0-9.]+ s", r"status: \1", text)  # wall time
        docs.append(_without_times(json.loads(text)))
    assert _digest(tmp_path / "p.parquet") == before
    assert docs[0] == docs[1]
    assert docs[0]["verdict"] == ("missing_physics" if seed % 2 else "consistent")


def _without_times(doc):
    """The document less its times (``time_s``, ``timings_s``, ``timings_cpu_s``)."""
    if isinstance(doc, dict):
        return {k: _without_times(v) for k, v in doc.items() if k not in TIMES}
    if isinstance(doc, list):
        return [_without_times(v) for v in doc]
    return doc


def test_cli_import_writes_parquet_and_leaves_the_source(tmp_path, capsys):
    src = tmp_path / "nmm_Q_raw.csv"
    phase = np.linspace(0, 359, 50)
    rows = "\n".join(f"{p}, {500 + np.sin(np.deg2rad(p))}, 0.0" for p in phase)
    src.write_text("Phase (deg), Radius, Roundness deviation\n" + rows + "\n")
    before = _digest(src)
    assert cli_main(["import", "nmm", str(src), "--out", str(tmp_path / "q.toml")]) == 0
    assert (
        cli_main(["import", "nmm", str(src), "--out", str(tmp_path / "p.toml"), "--parquet"]) == 0
    )
    assert _digest(src) == before
    assert (tmp_path / "p.parquet").read_bytes()[:4] == b"PAR1"
    a, b = load_recording(tmp_path / "q.toml"), load_recording(tmp_path / "p.toml")
    assert b.meta["data"] == "p.parquet"
    for k in a.columns:  # the CSV holds the shortest repr: it reads back exactly
        np.testing.assert_array_equal(a.columns[k], b.columns[k])


def test_cli_simulate_parquet_equals_csv_and_refuses_gzip_with_it(tmp_path, capsys):
    design = "examples/design-3plus1.toml"
    for name, extra in (("c", []), ("p", ["--parquet"])):
        out = str(tmp_path / f"{name}.toml")
        assert cli_main(["simulate", design, "--out", out, "--seed", "4", *extra]) == 0
    assert "table p.parquet" in capsys.readouterr().out
    a, b = load_recording(tmp_path / "c.toml"), load_recording(tmp_path / "p.toml")
    assert a.n_rows == b.n_rows > 1000
    for k in a.columns:
        np.testing.assert_array_equal(a.columns[k], b.columns[k])
    rc = cli_main(["simulate", design, "--out", str(tmp_path / "g.toml"), "--gzip", "--parquet"])
    assert rc == 2 and "not allowed with" in capsys.readouterr().err
    assert not (tmp_path / "g.toml").exists()
