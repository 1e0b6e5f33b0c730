"""Design files: a TOML description of one multihead encoder and its test bench.

See ``docs/design-file.md`` for the format. :func:`load_design` validates the whole file
before returning anything (unknown keys, wrong head counts, non-finite or out-of-range
values and time running backwards are refused with an
:class:`~encdesign.EncdesignInputError` naming the file, the key and what was expected);
:func:`encdesign.simulate.simulate_bench` turns a design into bench data, and
:func:`encdesign.simulate.simulate_recording` writes it as an ``encdesign-recording/1``
multihead recording.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import input_error
from ..io._recording import (
    finite_number,
    positive_number,
    read_toml,
    show,
)
from ..physics._kinematics import EncoderModel, make_model

__all__ = [
    "DESIGN_FORMAT",
    "BenchRun",
    "Design",
    "load_design",
    "parse_design",
]

DESIGN_FORMAT = "encdesign-design/1"
MAX_SAMPLES = 20_000_000  # refuse benches that would not fit in memory


@dataclasses.dataclass(frozen=True)
class BenchRun:
    """One acquisition at constant speed.

    Attributes:
        speed_rev_per_s: shaft speed, rev/s (non-zero; negative turns backwards).
        start_time_s, end_time_s: time span, s (end > start).
        sample_rate_hz: samples per second, Hz.
        start_angle_rad: shaft angle at ``start_time_s``, rad.
    """

    speed_rev_per_s: float = 1.0
    start_time_s: float = 0.0
    end_time_s: float = 1.0
    sample_rate_hz: float = 2048.0
    start_angle_rad: float = 0.0

    @property
    def n_samples(self) -> int:
        """Number of samples ``round((end - start) * rate)``."""
        return int(round((self.end_time_s - self.start_time_s) * self.sample_rate_hz))

    def times_and_angles(self) -> tuple[np.ndarray, np.ndarray]:
        """Sample times (s) and true shaft angles (rad, unwrapped)."""
        t = self.start_time_s + np.arange(self.n_samples) / self.sample_rate_hz
        theta = self.start_angle_rad + 2 * np.pi * self.speed_rev_per_s * (t - self.start_time_s)
        return t, theta


@dataclasses.dataclass(frozen=True)
class Design:
    """A validated design.

    Attributes:
        model: the kinematic model (:class:`~encdesign.EncoderModel`).
        head_angles_deg: nominal head azimuths, degrees.
        reference_head: index of the asymmetric reference head, or ``None``.
        grating_lines: lines per revolution, or ``None``.
        runs: the bench acquisitions.
        description: free text.
        path: the file it came from (``None`` when parsed from a dict).
    """

    model: EncoderModel
    head_angles_deg: tuple[float, ...]
    reference_head: int | None
    grating_lines: int | None
    runs: tuple[BenchRun, ...]
    description: str = ""
    path: Path | None = None

    @property
    def n_heads(self) -> int:
        """Number of heads."""
        return len(self.head_angles_deg)

    @property
    def symmetric_heads(self) -> tuple[int, ...]:
        """Indices of the heads other than the reference head."""
        return tuple(k for k in range(self.n_heads) if k != self.reference_head)

    def encoder_table(self) -> dict[str, Any]:
        """The ``[encoder]`` table of a multihead recording of this design."""
        enc: dict[str, Any] = {
            "optical_radius_m": float(self.model.disk.optical_radius_m),
            "head_angles_deg": [float(a) for a in self.head_angles_deg],
        }
        if self.reference_head is not None:
            enc["reference_head"] = self.reference_head
        if self.grating_lines is not None:
            enc["grating_lines"] = self.grating_lines
        return enc


# ----------------------------------------------------------------------------- checkers


_number = finite_number
_positive = positive_number


def _nonneg(where: str, v: object) -> float:
    x = _number(where, v)
    if x < 0:
        raise input_error(where, f"got {show(v)}", "a non-negative number")
    return x


def _within(where: str, v: object, limit: float, units: str, *, nonneg: bool = False) -> float:
    """A finite number with ``|v| <= limit`` (and ``>= 0`` with ``nonneg``)."""
    x = _number(where, v)
    if abs(x) > limit or (nonneg and x < 0):
        rng = f"0 <= value <= {limit:g}" if nonneg else f"|value| <= {limit:g}"
        raise input_error(where, f"got {show(v)}", f"{rng} {units}".strip())
    return x


# Documented ranges (docs/design-file.md): beyond them a value cannot be physical.
MAX_RADIUS_M = 10.0
MAX_SPEED_REV_PER_S = 1e4  # 600,000 rpm
MAX_TIME_S = 1e9  # 32 years
MAX_SAMPLE_RATE_HZ = 1e9
MAX_ANGLE_RAD = 1e6
MAX_FREQ_HZ = 1e6
MAX_NOISE_RAD = 0.1
MAX_GRATING_RAD = 0.1
MAX_GAP_M = 1.0


def _int(where: str, v: object, low: int = 0) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        raise input_error(where, f"got {v!r}", f"an integer >= {low}")
    return int(v)


def _list(
    where: str,
    v: object,
    length: int | None = None,
    what: str = "",
    limit: float | None = None,
    units: str = "",
) -> list[float]:
    if not isinstance(v, list):
        raise input_error(where, f"got {show(v)}", "a list of numbers")
    if length is None and len(v) > 10_000:
        raise input_error(where, f"{len(v)} values", "at most 10000")
    if length is not None and len(v) != length:
        raise input_error(
            where, f"{len(v)} values", f"{length}, one per {what}" if what else str(length)
        )
    if limit is not None:
        return [_within(f"{where}[{i}]", x, limit, units) for i, x in enumerate(v)]
    return [_number(f"{where}[{i}]", x) for i, x in enumerate(v)]


def _per_head(
    where: str,
    v: object,
    n_heads: int,
    nonneg: bool = False,
    limit: float = math.pi,
    units: str = "rad",
) -> list[float]:
    """A list with one value per head, or one number applied to every head."""
    if isinstance(v, list):
        vals = _list(where, v, n_heads, "head in [heads].angles_deg")
        wheres = [f"{where}[{i}]" for i in range(n_heads)]
    else:
        vals = [_number(where, v)] * n_heads
        wheres = [where] * n_heads
    for w, x in zip(wheres, vals):
        _within(w, x, limit, units, nonneg=nonneg)
    return vals


def _table(where: str, raw: Mapping[str, Any], name: str, allowed: set[str]) -> dict[str, Any]:
    tab = raw.get(name, {})
    if not isinstance(tab, dict):
        raise input_error(f"{where}: {name}", f"got {show(tab)}", f"a [{name}] table")
    unknown = sorted(set(tab) - allowed)
    if unknown:
        raise input_error(
            f"{where}: [{name}]", f"unknown key(s) {', '.join(unknown)}", f"only {sorted(allowed)}"
        )
    return tab


_TOP = {"format", "description", "disk", "heads", "motion", "bench"}
_DISK = {
    "optical_radius_m",
    "eccentricity_m",
    "tilt_rad",
    "grating_sin_rad",
    "grating_cos_rad",
    "grating_lines",
}
_HEADS = {
    "angles_deg",
    "reference_head",
    "placement_error_rad",
    "beam_tilt_rad",
    "gap_m",
    "noise_rad",
}
_MOTION = {
    "axial_cos_m",
    "axial_sin_m",
    "runout_amplitude_m",
    "runout_ratio",
    "runout_phase_rad",
    "runout_freq_hz",
}
_BENCH = {"runs"}
_RUN = {f.name for f in dataclasses.fields(BenchRun)}


def parse_design(raw: Mapping[str, Any], where: str = "design") -> Design:
    """Validate a design given as a dict (the parsed TOML); see ``docs/design-file.md``.

    Raises:
        EncdesignInputError: naming ``where``, the key and what was expected.
    """
    if not isinstance(raw, Mapping):
        raise input_error(where, "not a TOML table")
    unknown = sorted(set(raw) - _TOP)
    if unknown:
        raise input_error(where, f"unknown key(s) {', '.join(unknown)}", f"only {sorted(_TOP)}")
    fmt = raw.get("format", DESIGN_FORMAT)
    if fmt != DESIGN_FORMAT:
        raise input_error(f"{where}: format", f"got {fmt!r}", repr(DESIGN_FORMAT))
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise input_error(f"{where}: description", f"got {description!r}", "a string")

    disk = _table(where, raw, "disk", _DISK)
    heads = _table(where, raw, "heads", _HEADS)
    motion = _table(where, raw, "motion", _MOTION)
    bench = _table(where, raw, "bench", _BENCH)
    if "optical_radius_m" not in disk:
        raise input_error(f"{where}: [disk]", "missing key 'optical_radius_m'")
    if "angles_deg" not in heads:
        raise input_error(f"{where}: [heads]", "missing key 'angles_deg'")

    w = f"{where}: [disk]."
    radius = _positive(w + "optical_radius_m", disk["optical_radius_m"])
    if radius > MAX_RADIUS_M:
        raise input_error(
            w + "optical_radius_m", f"got {show(radius)}", f"0 < value <= {MAX_RADIUS_M:g} m"
        )
    ecc = _list(w + "eccentricity_m", disk.get("eccentricity_m", [0.0, 0.0]), 2, "axis (x, y)")
    for i, e in enumerate(ecc):
        _within(f"{w}eccentricity_m[{i}]", e, radius, "m (the radius)")
    tilt = _list(w + "tilt_rad", disk.get("tilt_rad", [0.0, 0.0]), 2, "axis (x, y)")
    for i, t in enumerate(tilt):
        if abs(t) >= 0.5:
            raise input_error(f"{w}tilt_rad[{i}]", f"got {show(t)}", "|tilt| < 0.5 rad")
    gs = _list(
        w + "grating_sin_rad", disk.get("grating_sin_rad", []), limit=MAX_GRATING_RAD, units="rad"
    )
    gc = _list(
        w + "grating_cos_rad", disk.get("grating_cos_rad", []), limit=MAX_GRATING_RAD, units="rad"
    )
    lines = disk.get("grating_lines")
    if lines is not None:
        lines = _int(w + "grating_lines", lines, 1)
        if lines > 10**9:
            raise input_error(w + "grating_lines", f"got {lines}", "an integer 1 … 1000000000")

    w = f"{where}: [heads]."
    angles_raw = heads["angles_deg"]
    if not isinstance(angles_raw, list) or not angles_raw:
        raise input_error(
            w + "angles_deg", f"got {show(angles_raw)}", "a non-empty list of degrees"
        )
    if len(angles_raw) > 1000:
        raise input_error(w + "angles_deg", f"{len(angles_raw)} heads", "at most 1000 heads")
    angles = _list(w + "angles_deg", angles_raw, limit=360.0, units="deg")
    n_heads = len(angles)
    ref = heads.get("reference_head")
    if ref is not None:
        ref = _int(w + "reference_head", ref, 0)
        if ref >= n_heads:
            raise input_error(
                w + "reference_head", f"got {ref}", f"an index < {n_heads} (number of angles_deg)"
            )
    placement = _per_head(
        w + "placement_error_rad", heads.get("placement_error_rad", 0.0), n_heads, limit=0.1
    )
    beam = _per_head(w + "beam_tilt_rad", heads.get("beam_tilt_rad", 0.0), n_heads)
    for i, b in enumerate(beam):
        if abs(b) >= 1.0:
            raise input_error(f"{w}beam_tilt_rad[{i}]", f"got {show(b)}", "|tilt| < 1 rad")
    gap = _positive(w + "gap_m", heads.get("gap_m", 1e-3))
    if gap > MAX_GAP_M:
        raise input_error(w + "gap_m", f"got {show(gap)}", f"0 < value <= {MAX_GAP_M:g} m")
    noise = _per_head(
        w + "noise_rad", heads.get("noise_rad", 0.0), n_heads, nonneg=True, limit=MAX_NOISE_RAD
    )

    w = f"{where}: [motion]."
    ac = _list(w + "axial_cos_m", motion.get("axial_cos_m", []), limit=radius, units="m")
    asn = _list(w + "axial_sin_m", motion.get("axial_sin_m", []), limit=radius, units="m")
    runout = _within(
        w + "runout_amplitude_m", motion.get("runout_amplitude_m", 0.0), radius, "m", nonneg=True
    )
    ratio = _within(w + "runout_ratio", motion.get("runout_ratio", 0.0), 1e3, "")
    rphase = _within(
        w + "runout_phase_rad", motion.get("runout_phase_rad", 0.0), MAX_ANGLE_RAD, "rad"
    )
    rfreq = _within(w + "runout_freq_hz", motion.get("runout_freq_hz", 0.0), MAX_FREQ_HZ, "Hz")

    runs_raw = bench.get("runs", [{}])
    if not isinstance(runs_raw, list) or not runs_raw:
        raise input_error(
            f"{where}: [bench].runs", f"got {show(runs_raw)[:80]}", "[[bench.runs]] tables"
        )
    runs = []
    total = 0
    for i, r in enumerate(runs_raw):
        wr = f"{where}: [[bench.runs]] #{i}"
        if not isinstance(r, dict):
            raise input_error(wr, f"got {show(r)[:80]}", "a table")
        unknown = sorted(set(r) - _RUN)
        if unknown:
            raise input_error(wr, f"unknown key(s) {', '.join(unknown)}", f"only {sorted(_RUN)}")
        d = BenchRun()
        run = BenchRun(
            speed_rev_per_s=_number(
                f"{wr}.speed_rev_per_s", r.get("speed_rev_per_s", d.speed_rev_per_s)
            ),
            start_time_s=_number(f"{wr}.start_time_s", r.get("start_time_s", d.start_time_s)),
            end_time_s=_number(f"{wr}.end_time_s", r.get("end_time_s", d.end_time_s)),
            sample_rate_hz=_positive(
                f"{wr}.sample_rate_hz", r.get("sample_rate_hz", d.sample_rate_hz)
            ),
            start_angle_rad=_number(
                f"{wr}.start_angle_rad", r.get("start_angle_rad", d.start_angle_rad)
            ),
        )
        for key, limit, units in (
            ("speed_rev_per_s", MAX_SPEED_REV_PER_S, "rev/s"),
            ("start_time_s", MAX_TIME_S, "s"),
            ("end_time_s", MAX_TIME_S, "s"),
            ("sample_rate_hz", MAX_SAMPLE_RATE_HZ, "Hz"),
            ("start_angle_rad", MAX_ANGLE_RAD, "rad"),
        ):
            _within(f"{wr}.{key}", getattr(run, key), limit, units)
        if run.speed_rev_per_s == 0:
            raise input_error(f"{wr}.speed_rev_per_s", "got 0", "a non-zero speed in rev/s")
        if run.end_time_s <= run.start_time_s:
            raise input_error(
                f"{wr}.end_time_s",
                f"time goes backwards or stands still (start_time_s {show(run.start_time_s)}, "
                f"end_time_s {show(run.end_time_s)})",
                "end_time_s > start_time_s",
            )
        if (run.end_time_s - run.start_time_s) * run.sample_rate_hz > MAX_SAMPLES:
            raise input_error(
                wr,
                f"{(run.end_time_s - run.start_time_s) * run.sample_rate_hz:.4g} samples",
                f"at most {MAX_SAMPLES} samples in all runs together",
            )
        if run.n_samples < 2:
            raise input_error(wr, f"{run.n_samples} sample(s)", "at least 2 samples per run")
        total += run.n_samples
        runs.append(run)
    if total > MAX_SAMPLES:
        raise input_error(f"{where}: [bench]", f"{total} samples", f"at most {MAX_SAMPLES}")

    try:
        model = make_model(
            radius,
            np.deg2rad(angles),
            eccentricity_m=ecc,
            tilt_rad=tilt,
            grating_sin_rad=gs,
            grating_cos_rad=gc,
            placement_error_rad=placement,
            beam_tilt_rad=beam,
            gap_m=gap,
            noise_rad=noise,
            axial_cos_m=ac,
            axial_sin_m=asn,
            runout_amplitude_m=runout,
            runout_ratio=ratio,
            runout_phase_rad=rphase,
            runout_freq_hz=rfreq,
        )
    except ValueError as exc:  # pragma: no cover - the checks above should catch everything
        raise input_error(where, str(exc)) from None
    return Design(
        model=model,
        head_angles_deg=tuple(angles),
        reference_head=ref,
        grating_lines=lines,
        runs=tuple(runs),
        description=description,
    )


def load_design(path: str | os.PathLike) -> Design:
    """Load and validate a design TOML file (never modifies it).

    Raises:
        EncdesignInputError: the file is missing, not TOML, or breaks the format.
    """
    path = Path(path)
    return dataclasses.replace(parse_design(read_toml(path), str(path)), path=path)
