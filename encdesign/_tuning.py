"""Defaults read off a measured sweep (``benchmarks/kinematics_sweep.py``), kept in
``_tuning.json`` beside this file: CPU devices per core (``encdesign._cpu``) and readings
per chunk of :func:`encdesign.head_errors_batch`. ``kinematics_sweep.py --write-defaults``
rewrites the file; its ``source`` says which measurement each value comes from."""

from __future__ import annotations

import json
from pathlib import Path

PATH = Path(__file__).with_name("_tuning.json")
_DATA = json.loads(PATH.read_text())

DEVICES_PER_CORE: float = float(_DATA["devices_per_core"])
"""CPU devices per core (the device count is ``max(1, round(cores * this))``)."""
CHUNK_READINGS: int = int(_DATA["chunk_readings"])
"""Readings per chunk of :func:`encdesign.head_errors_batch` on one device."""
