"""Benchmark: peak memory and time of the streaming commands against row count (issue 12).

For each row count ``N`` (default 10^5, 10^6, 10^7) every step runs in a fresh process,
which reports its own peak resident set size (``ru_maxrss``):

* ``encdesign simulate`` of a 4-head design whose one run has ``N`` samples (the bench is
  simulated in chunks of 65,536 samples and the CSV written in chunks of 65,536 rows);
* ``load_recording`` of that recording (the block-wise CSV reader the finders use);
* ``encdesign import odrive`` of a synthetic ODrive ``.npy`` with ``N`` samples (memory
  mapped, checked in chunks).

A plain-NumPy baseline reads the same CSV with ``numpy.loadtxt`` (C parser, everything in
memory at once).

    python benchmarks/io.py --rows 100000 1000000 10000000 --json results/bench-io.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

DESIGN = """\
format = "encdesign-design/1"
[disk]
optical_radius_m = 0.0254
eccentricity_m = [5e-6, 0.0]
[heads]
angles_deg = [0.0, 120.0, 240.0, 22.0]
reference_head = 3
noise_rad = 5e-8
[[bench.runs]]
speed_rev_per_s = 1.0
end_time_s = {end}
sample_rate_hz = 1000.0
"""

_CHILD = textwrap.dedent(
    """
    import json, resource, sys, time
    t0 = time.perf_counter()
    step = sys.argv[1]
    if step == "cli":
        from encdesign.cli import main
        rc = main(sys.argv[2:])
    elif step == "load":
        from encdesign.io._recording import load_recording
        rc = load_recording(sys.argv[2]).n_rows
    elif step == "numpy":
        import numpy as np
        rc = np.loadtxt(sys.argv[2], delimiter=",", skiprows=1).shape[0]
    elif step == "npy":
        import numpy as np
        n = int(sys.argv[3])
        t = np.arange(n) / 1000.0
        np.save(sys.argv[2], np.stack([t, 819.2 * t, 0.1 * np.sin(t)]))
        rc = 0
    print(json.dumps({"rc": rc, "s": time.perf_counter() - t0,
                      "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
    """
)


def _child(*argv: str) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, *argv],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    if out.returncode != 0:
        raise RuntimeError(f"{argv[:2]} failed: {out.stderr.strip()[-500:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(rows: list[int]) -> list[dict]:
    results = []
    for n in rows:
        with tempfile.TemporaryDirectory(prefix="encdesign-bench-io-") as d:
            d = Path(d)
            (d / "design.toml").write_text(DESIGN.format(end=n / 1000.0))
            sim = _child("cli", "simulate", str(d / "design.toml"), "--out", str(d / "r.toml"))
            size_mb = (d / "r.csv").stat().st_size / 2**20
            load = _child("load", str(d / "r.toml"))
            base = _child("numpy", str(d / "r.csv")) if n <= 1_000_000 else None
            _child("npy", str(d / "od.npy"), str(n))
            imp = _child("cli", "import", "odrive", str(d / "od.npy"), "--out", str(d / "od.toml"))
            row = {
                "rows": n,
                "csv_mb": round(size_mb, 1),
                "simulate": sim,
                "load_recording": load,
                "import_odrive": imp,
                "numpy_loadtxt": base,
            }
            print(
                f"{n:>10,d} rows ({size_mb:7.1f} MB CSV): simulate {sim['s']:6.1f} s "
                f"{sim['peak_rss_mb']:6.0f} MB | load {load['s']:6.1f} s "
                f"{load['peak_rss_mb']:6.0f} MB | import odrive {imp['s']:6.1f} s "
                f"{imp['peak_rss_mb']:6.0f} MB"
                + (
                    f" | numpy.loadtxt {base['s']:5.1f} s {base['peak_rss_mb']:6.0f} MB"
                    if base
                    else ""
                ),
                flush=True,
            )
            results.append(row)
    return results


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, nargs="+", default=[100_000, 1_000_000, 10_000_000])
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    results = run(args.rows)
    if args.json is not None:
        from encdesign.io._study import write_json

        write_json(
            args.json,
            {
                "machine": platform.platform(),
                "cpus": os.cpu_count(),
                "results": results,
            },
        )
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
