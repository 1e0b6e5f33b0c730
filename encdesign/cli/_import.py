"""``encdesign import``: convert public measured data into recordings."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..io import _realdata

HELP = (
    "convert measured data (NmmQuad CSV, ODrive .npy, moteus encoder sweep, MagAlpha CSV, "
    "or the whole realdata folder)"
)

IMPORTERS = {
    "nmm": _realdata.import_nmm,
    "odrive": _realdata.import_odrive,
    "moteus": _realdata.import_moteus,
    "magalpha": _realdata.import_magalpha,
}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "source", choices=[*IMPORTERS, "realdata"], help="what SRC is (realdata: a folder)"
    )
    parser.add_argument("src", type=Path, help="input file (or folder for 'realdata')")
    parser.add_argument(
        "--out", type=Path, required=True, help="output recording TOML (folder for 'realdata')"
    )


def run(args: argparse.Namespace) -> int:
    if args.source == "realdata":
        for p in _realdata.import_realdata_folder(args.src, args.out):
            print(f"wrote {p}")
        return 0
    rec = IMPORTERS[args.source](args.src, args.out)
    print(f"wrote {rec.path} ({rec.kind}, {rec.n_rows} rows)")
    return 0
