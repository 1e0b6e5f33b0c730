"""``encdesign import``: convert public measured data into recordings."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._main import guard_outputs

HELP = (
    "convert measured data (NmmQuad CSV, ODrive .npy, moteus encoder sweep, MagAlpha CSV, "
    "ServoProject optical-encoder capture, or the whole realdata folder)"
)

IMPORTERS = ("nmm", "odrive", "moteus", "magalpha", "servo")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "source", choices=[*IMPORTERS, "realdata"], help="what SRC is (realdata: a folder)"
    )
    parser.add_argument("src", type=Path, help="input file (or folder for 'realdata')")
    parser.add_argument(
        "--out", type=Path, required=True, help="output recording TOML (folder for 'realdata')"
    )
    parser.add_argument(
        "--parquet", action="store_true", help="write the table as Parquet (NAME.parquet)"
    )


def run(args: argparse.Namespace) -> int:
    from .. import io
    from ..errors import input_error
    from ..io import import_realdata_folder, realdata_jobs, recording_output_files

    if args.source == "realdata":
        if not args.src.is_dir():
            raise input_error(f"SRC {args.src}", "not a folder", "the realdata folder")
        jobs = realdata_jobs(args.src, args.out)
        inputs = [("SRC", src) for _, src, _ in jobs]
        outputs = [
            ("--out", p)
            for _, _, dst in jobs
            for p in recording_output_files(dst, parquet=args.parquet, label="--out")
        ]
        with guard_outputs(inputs, outputs, folders=[("--out", args.out)]):
            written = import_realdata_folder(args.src, args.out, parquet=args.parquet)
        for p in written:
            print(f"wrote {p}")
        return 0
    outputs = [
        ("--out", p) for p in recording_output_files(args.out, parquet=args.parquet, label="--out")
    ]
    fn = getattr(io, f"import_{args.source}")
    with guard_outputs([("SRC", args.src)], outputs):
        rec = fn(args.src, args.out, parquet=args.parquet)
    print(f"wrote {rec.path} ({rec.kind}, {rec.n_rows} rows)")
    return 0
