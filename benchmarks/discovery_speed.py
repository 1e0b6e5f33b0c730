"""Benchmark: discovery's share of the wall time of a 4-head x 16,000-sample diagnosis (issue 41:
at most 50 %). The records of ``benchmarks/diagnose.py`` (clean, a vibration) and
out-of-catalog records of ``encdesign/simulate/_outside.py`` at 5x the noise; one process,
compilation warmed up on the first record::

    python benchmarks/discovery_speed.py torque_ripple,head_defect,direction_lag out.json
"""

import json
import resource
import sys
import time

sys.path.insert(0, "benchmarks")
import diagnose as BD  # noqa: E402
import discovery as B  # noqa: E402
import numpy as np  # noqa: E402

from encdesign.diagnose._dispatch import diagnose  # noqa: E402
from encdesign.diagnose.engine import _engine  # noqa: E402

_engine.discover = B._capture


def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


out = []
diagnose(BD._bench_recording(16000, 4, 5, False))  # warm-up (compilation)
cases = [
    ("bench clean", lambda: BD._bench_recording(16000, 4, 5, False)),
    ("bench vibration", lambda: BD._bench_recording(16000, 4, 5, True)),
]
for cls in sys.argv[1].split(","):
    cases.append(
        (
            cls + " 5x",
            lambda cls=cls: B.outside_record(
                np.random.default_rng(7), cls, 5.0, "multihead", 16000
            )[0],
        )
    )
for name, mk in cases:
    rec = mk()
    B._CAP.clear()
    t0, c0 = time.perf_counter(), cpu()
    d = diagnose(rec)
    t1, c1 = time.perf_counter(), cpu()
    ds = B._CAP.get("discovery_s", 0.0)
    row = dict(
        case=name,
        rows=rec.n_rows,
        wall_s=t1 - t0,
        cpu_s=c1 - c0,
        discovery_wall_s=ds,
        added_share=ds / max(t1 - t0 - ds, 1e-9),
        verdict=d.verdict,
    )
    out.append(row)
    print(json.dumps(row), flush=True)
json.dump(out, open(sys.argv[2], "w"), indent=1)
