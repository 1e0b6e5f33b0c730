"""Canonical configurations shared by the tests (one place, parametrised over)."""

# --- quadrature signal layer (issue 6) ---
# A 20 um pitch linear encoder (seed 002) with moderate signal errors: offsets B/A,
# amplitude ratio A1/A2, phase error of S_A (rad).
QUADRATURE_PITCH_M = 20e-6
QUADRATURE_ERRORS = {
    "offset_a": 0.04,
    "offset_b": -0.03,
    "amplitude_ratio": 0.95,
    "phase_error_rad": 0.05,
}

# --- kinematics, encoder theorem, self-compensation (issue 2) ---
# Cramer's simulation case (seed 000, figs. 7-8): 2.54 cm optical radius, 5 um centering
# error, 6 mrad tilt, 5 urad grating mode 3 and 2.5 urad mode 4; heads 0/120/240 deg plus
# a reference head at 22 deg (index 3).
CRAMER_RADIUS_M = 0.0254
CRAMER_ECCENTRICITY_M = 5e-6
CRAMER_TILT_RAD = 6e-3
CRAMER_GRATING_SIN_RAD = (0.0, 0.0, 5e-6, 0.0)
CRAMER_GRATING_COS_RAD = (0.0, 0.0, 0.0, 2.5e-6)
CRAMER_HEADS_DEG = (0.0, 120.0, 240.0, 22.0)
CRAMER_REFERENCE_HEAD = 3


def cramer_model(**overrides):
    """The Cramer 3+1 encoder as an :class:`encdesign.EncoderModel` (keyword overrides
    go to :func:`encdesign.make_model`)."""
    import numpy as np

    from encdesign import make_model

    kw = dict(
        eccentricity_m=(CRAMER_ECCENTRICITY_M, 0.0),
        tilt_rad=(CRAMER_TILT_RAD, 0.0),
        grating_sin_rad=CRAMER_GRATING_SIN_RAD,
        grating_cos_rad=CRAMER_GRATING_COS_RAD,
    )
    kw.update(overrides)
    return make_model(CRAMER_RADIUS_M, np.deg2rad(CRAMER_HEADS_DEG), **kw)


# --- shifted-delta-sum timing model (issue 3) ---
SDS_TEST_MARKS = 240  # marks per revolution in the SDS tests (the physics does not need 10,000)


def sds_reference(n_fixed: int = 2, n_moving: int = 2, marks: int = SDS_TEST_MARKS):
    """The seed's first SDS device (6 pole pairs, 18 coils, six-step drive, 10 rev/s) with
    ``marks`` marks per disk and equally spaced sensors (:func:`encdesign.reference_design`)."""
    from encdesign import reference_design

    return reference_design(n_fixed, n_moving, marks_per_rev=marks)


# --- discrepancy finder (issue 5) ---
DIAGNOSE_TEST_SAMPLES_PER_RUN = 600  # rows per run of the finder's test benches (3 runs)
DIAGNOSE_TEST_AMPLITUDE = 4.0  # hidden-effect amplitude in units of the read noise


def validate_diagnosis(doc) -> None:
    """Validate a diagnosis document (as written to JSON) against the shipped JSON Schema."""
    import json

    import jsonschema

    from encdesign.diagnose import SCHEMA_PATH
    from encdesign.io._study import to_jsonable

    schema = json.loads(SCHEMA_PATH.read_text())
    jsonschema.validate(json.loads(json.dumps(to_jsonable(doc))), schema)


# --- calibration: dual closure (issue 13) ---
# A polygon with 2 arcsec RMS face errors read with 0.01 arcsec noise per null, on an
# instrument whose error is the seed's first device with both pairs in round numbers:
# 0.2 arcsec at order 1 (axial runout through tilted optics) and 0.58 arcsec at order 2.
CLOSURE_ARCSEC = 3.141592653589793 / (180 * 3600)
CLOSURE_FACE_RAD = 2.0 * CLOSURE_ARCSEC
CLOSURE_SIGMA_RAD = 0.01 * CLOSURE_ARCSEC


def closure_instrument_error(phi_rad):
    """Instrument error (rad) at platform angles ``phi_rad`` (any shape)."""
    import numpy as np

    phi = np.asarray(phi_rad, dtype=float)
    return CLOSURE_ARCSEC * (0.2 * np.sin(phi + 0.4) + 0.58 * np.cos(2 * phi + 1.1))


def write_small_closure_recording(path):
    """A 12-face closure recording of :func:`closure_instrument_error` (perfect faces and
    settings, 0.1 urad reading noise, key 0) at ``path``; returns what
    :func:`encdesign.io._closure_recording.write_closure_recording` returns. The CLI contract
    test and ``benchmarks/reliability_probes.py`` feed it to ``calibrate closure``."""
    import jax
    import numpy as np

    from encdesign.io._closure_recording import write_closure_recording
    from encdesign.simulate import simulate_closure_readings

    readings = simulate_closure_readings(
        closure_instrument_error,
        12,
        list(range(12)),
        face_error_rad=np.zeros(12),
        setting_offset_rad=np.zeros(12),
        sigma_reading_rad=1e-7,
        key=jax.random.PRNGKey(0),
    )
    return write_closure_recording(path, readings)


# --- scale-out (issue 15) ---
# A small 3+1 build (coarse angles, low orders: compiles in seconds) and the tolerance set
# of benchmarks/optimize.py, for the distributed Monte Carlo agreement tests.
SCALE_DESIGN = dict(
    radius_m=0.0254,
    reference_angle_rad=0.3157,
    tilt_rad=6e-3,
    n_heads=3,
    max_order=4,
    grating_orders=4,
    axial_orders=2,
    n_angles=32,
)
SCALE_TOLERANCES = dict(
    eccentricity=5e-6,
    tilt=1e-3,
    placement=2e-4,
    grating=5e-6,
    beam_tilt=1e-3,
    axial_runout=2e-6,
    noise=2e-7,
)
SCALE_BUILDS = 203  # not a multiple of 2 or 4: the last shard is short


def slow_wobble_bench(speeds_rev_s=(0.7, 1.2, 1.7), nu: float = 0.4, n_per_run: int = 4000, seed=0):
    """Three heads, one run per speed (4 s each at 1 kHz, 0.5 urad noise, a 3 urad order-2
    disk error, per-run zeros) with a 3 urad shaft wobble at the fractional order ``nu``:
    at order 0.4 fewer than 3 cycles in every run (issue 22's example)."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng(seed)
    alpha = np.array([0.0, 2.1, 4.2])
    cols: dict[str, list] = {"t": [], "run": [], "theta_ref": [], "h0": [], "h1": [], "h2": []}
    for r, f in enumerate(speeds_rev_s):
        t = np.arange(n_per_run) / 1000.0
        th = 2 * np.pi * f * t + rng.uniform(0, 6)
        ph = rng.uniform(0, 6.3)
        cols["t"].append(t)
        cols["run"].append(np.full(n_per_run, r))
        cols["theta_ref"].append(th + rng.uniform(-3, 3))
        for k in range(3):
            e = 3e-6 * np.sin(2 * (th - alpha[k])) + 3e-6 * np.sin(nu * th + ph - alpha[k])
            e = e + rng.normal(0, 0.5e-6, n_per_run)
            cols[f"h{k}"].append(th + e + rng.uniform(-3, 3))
    cols = {k: np.concatenate(v) for k, v in cols.items()}
    enc = {"optical_radius_m": 0.02, "head_angles_deg": np.degrees(alpha).tolist()}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


def stepped_sensor_record(
    seed: int,
    n_steps: int = 90,
    turns: float = 3.0,
    both: bool = True,
    hysteresis_rad: float = 0.0,
    lsb_rad: float = 0.0,
    noise_rad: float = 2e-5,
):
    """A static stepped calibration of a sensor against a reference (issue 22, item 5).

    The rig steps the shaft by large, uneven angles (``turns`` turns in ``n_steps`` steps of
    0.2-1.8x the mean: no steady motion),
    settles and logs one row per step; ``t`` is the step index. ``both``: the same positions
    again backwards. The sensor reads ``theta + e(theta) + h d / 2 + noise`` with an error
    function of orders 1-4 (about 30x the noise), ``d`` the approach direction, quantized to
    ``lsb_rad`` (0: not). Returns (recording, truth dict)."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng(seed)
    step = turns * 2 * np.pi / n_steps
    fwd = np.cumsum(step * rng.uniform(0.2, 1.8, n_steps)) + rng.uniform(0, 6.3)
    th = np.concatenate([fwd, fwd[::-1] - 0.3 * step]) if both else fwd
    d = np.concatenate([np.ones(n_steps), -np.ones(n_steps)]) if both else np.ones(n_steps)
    amps = 30 * noise_rad * rng.uniform(0.3, 1.0, 4) / np.arange(1, 5)
    ph = rng.uniform(0, 6.3, 4)
    e = sum(amps[m - 1] * np.sin(m * th + ph[m - 1]) for m in range(1, 5))
    h = th + e + 0.5 * hysteresis_rad * d + rng.normal(0, noise_rad, th.size) + 0.7
    if lsb_rad > 0:
        h = np.round(h / lsb_rad) * lsb_rad
    cols = {"t": np.arange(th.size, dtype=float), "run": np.zeros(th.size, int)}
    cols["theta_ref"] = th
    cols["h0"] = h
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), dict(amps=amps, hysteresis_rad=hysteresis_rad)


def late_stamps_record(seed: int, n_gaps: int = 2, fs: float = 500.0, noise_rad: float = 2e-5):
    """A sensor against a reference, 4 steady turns at 500 Hz, with ``n_gaps`` logger stalls
    (0.2-0.5 s of rows lost) after each of which the 5-20 samples the logger buffered are
    stamped late, on arrival (1-10 % of an interval apart); the shaft angles are those of the
    true sample times (issue 22, item 4). Returns (recording, number of late rows per gap)."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng(seed)
    w = 2 * np.pi * rng.uniform(0.8, 1.5)
    n = int(4 * 2 * np.pi / w * fs)
    tt = np.arange(n) / fs
    keep, t, late = np.ones(n, bool), tt.copy(), []
    starts = np.sort(rng.choice(np.arange(n // 5, 4 * n // 5, n // 10), n_gaps, replace=False))
    for g in starts:
        gap = int(rng.uniform(0.2, 0.5) * fs)
        keep[g : g + gap] = False
        k = int(rng.integers(5, 21))
        t[g + gap : g + gap + k] = (
            tt[g + gap + k] - np.arange(k, 0, -1) * rng.uniform(0.01, 0.1) / fs
        )
        late.append(k)
    th = w * tt + rng.uniform(0, 6)
    amps, ph = 30 * noise_rad * rng.uniform(0.3, 1.0, 3) / np.arange(1, 4), rng.uniform(0, 6.3, 3)
    e = sum(amps[m] * np.sin((m + 1) * th + ph[m]) for m in range(3))
    h = th + e + rng.normal(0, noise_rad, n) + 0.7
    cols = {"t": t[keep], "theta_ref": th[keep], "h0": h[keep]}
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), late


def reversal_record(seed: int, shape: str, n: int = 1600, fs: float = 400.0, noise: float = 2e-5):
    """Three heads, no reference: a steady turn forward, a reversal at mid-record, back at the
    same speed (1.2-1.8 rev/s; ``n`` rows whatever the speed, so the fits compile once). Head
    1 carries ``shape``: ``"reversal_step"`` a step of 10 noise units at the reversal (a
    load reversal no catalog effect covers: no reference, so no direction term),
    ``"drift"`` a slow linear drift of 20 noise units over the record (issue 22, item 4).
    Returns (recording, truth dict with ``t_reversal_s``)."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng(seed)
    w = 2 * np.pi * rng.uniform(1.2, 1.8)
    t = np.arange(n) / fs
    k = n // 2
    th = np.where(np.arange(n) < k, w * t, 2 * w * t[k] - w * t) + rng.uniform(0, 6)
    alpha = np.array([0.0, 2.1, 4.2])
    cols = {"t": t}
    for j in range(3):
        e = 1e-5 * np.sin(2 * (th - alpha[j]) + 1.0) + 5e-6 * np.sin(3 * (th - alpha[j]))
        if j == 1 and shape == "reversal_step":
            e = e + 10 * noise * (np.arange(n) >= k)
        elif j == 1 and shape == "drift":
            e = e + 20 * noise * (t / t[-1] - 0.5)
        cols[f"h{j}"] = th + e + rng.normal(0, noise, n) + rng.uniform(-1, 1)
    enc = {"head_angles_deg": np.degrees(alpha).tolist(), "optical_radius_m": 0.02}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), dict(t_reversal_s=float(t[k]))


def dwell_reversal_record(seed: int, back: float = 0.1, fs: float = 500.0, noise: float = 2e-5):
    """A sensor against a reference driven forward / stop / back (issue 22, item 4): 3 turns
    forward at 0.8-1.5 rev/s, a dwell of 0.05-1 s, then ``back`` of that angle backwards,
    with 0.05-0.15 s speed ramps; the sensor's reading is offset by ``h d / 2`` (``h`` = 10
    noise units, ``d`` the direction of the last motion: hysteresis holds through the
    dwell). Returns (recording, truth dict with ``hysteresis_rad``)."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng(seed)
    w = 2 * np.pi * rng.uniform(0.8, 1.5)
    k = max(1, int(rng.uniform(0.05, 0.15) * fs))
    t1 = 3 * 2 * np.pi / w
    plan = [(t1, 1.0), (rng.uniform(0.05, 1.0), 0.0), (back * t1, -1.0)]
    v = np.concatenate([np.full(int(T * fs), s * w) for T, s in plan])
    v = np.convolve(np.pad(v, k, mode="edge"), np.ones(k) / k, mode="same")[k:-k]
    th = np.cumsum(v) / fs + rng.uniform(0, 6)
    d = np.sign(v) * (np.abs(v) > 1e-9)
    for i in range(1, d.size):  # the direction of the last motion, through the dwell
        d[i] = d[i] if d[i] else d[i - 1]
    amps, ph = 30 * noise * rng.uniform(0.3, 1.0, 3) / np.arange(1, 4), rng.uniform(0, 6.3, 3)
    e = sum(amps[m] * np.sin((m + 1) * th + ph[m]) for m in range(3))
    h = th + e + 5 * noise * d + rng.normal(0, noise, th.size) + 0.7
    cols = {"t": np.arange(th.size) / fs, "theta_ref": th, "h0": h}
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), dict(hysteresis_rad=10 * noise)


def return_move_record(seed: int, share: float = 0.05, fs: float = 500.0, noise: float = 2e-5):
    """A sensor against a reference that first moves back at 3x the steady speed into its
    start position for ``share`` of the rows (a return-to-zero move, reversing without a
    stop), the heads shaken by 20 noise units at 7 Hz while it lasts (as the concealed
    benchmark's return move), then 3 turns forward at 0.8-1.5 rev/s (issue 22: a move
    back before the run is not a move back after a stop)."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng(seed)
    w = 2 * np.pi * rng.uniform(0.8, 1.5)
    n = int(3 * 2 * np.pi / w * fs / (1 - share))
    k = int(share * n)
    t = np.arange(n) / fs
    th = np.where(np.arange(n) < k, 3 * w * (k - np.arange(n)) / fs, w * (np.arange(n) - k) / fs)
    th = th + rng.uniform(0, 6)
    amps, ph = 30 * noise * rng.uniform(0.3, 1.0, 3) / np.arange(1, 4), rng.uniform(0, 6.3, 3)
    e = sum(amps[m] * np.sin((m + 1) * th + ph[m]) for m in range(3))
    shake = np.where(np.arange(n) < k, 20 * noise * np.sin(2 * np.pi * 7.0 * t), 0.0)
    cols = {"t": t, "theta_ref": th, "h0": th + e + shake + rng.normal(0, noise, n) + 0.7}
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


def steady_start_record(seed: int, ramp_s: float = 0.0, fs: float = 500.0, noise: float = 2e-5):
    """A sensor against a reference turning 4 turns at 0.8-1.5 rev/s, with 5 % of an
    interval of sampling jitter and a 2 % speed ripple at order 3: steady from its first row
    (``ramp_s`` = 0) or after a linear start-up ramp of ``ramp_s`` (issue 22, item 4)."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng(seed)
    w = 2 * np.pi * rng.uniform(0.8, 1.5)
    n = int((4 * 2 * np.pi / w + ramp_s) * fs)
    t = np.arange(n) / fs + rng.normal(0, 0.05 / fs, n)
    tc = np.clip(t, 0, None)
    th = w * np.where(tc < ramp_s, tc**2 / (2 * ramp_s) if ramp_s else 0, tc - ramp_s / 2)
    th = th + rng.uniform(0, 6)
    th = th + 0.02 / 3 * np.sin(3 * th + 1.0)
    amps, ph = 30 * noise * rng.uniform(0.3, 1.0, 3) / np.arange(1, 4), rng.uniform(0, 6.3, 3)
    e = sum(amps[m] * np.sin((m + 1) * th + ph[m]) for m in range(3))
    cols = {"t": t, "theta_ref": th, "h0": th + e + rng.normal(0, noise, n) + 0.7}
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


def angle_step_record(seed: int, accumulate: bool = False, fs: float = 500.0, noise: float = 2e-5):
    """A sensor against a reference, 5 turns at 0.8-1.5 rev/s, whose error function has a
    box of 60 noise units on an arc of 1-2.5 rad (a potentiometer's track, a magnet's
    segment: a step up and a step down at fixed angles on every pass; issue 22, item 4).
    ``accumulate``: instead, 60 noise units of counts lost at one angle on every pass (a
    disk defect: steps in time that never return). Returns (recording, truth dict with
    ``angles_rad`` (the box's edges) and ``size_rad``)."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng(seed)
    w = 2 * np.pi * rng.uniform(0.8, 1.5)
    n = int(5 * 2 * np.pi / w * fs)
    t = np.arange(n) / fs
    th = w * t + rng.uniform(0, 6)
    a0, width, size = rng.uniform(0, 2 * np.pi), rng.uniform(1.0, 2.5), 60 * noise
    if accumulate:
        e = -size * np.floor((th - a0) / (2 * np.pi))
    else:
        e = size * (np.mod(th - a0, 2 * np.pi) < width)
    amps, ph = 30 * noise * rng.uniform(0.3, 1.0, 3) / np.arange(1, 4), rng.uniform(0, 6.3, 3)
    e = e + sum(amps[m] * np.sin((m + 1) * th + ph[m]) for m in range(3))
    cols = {"t": t, "theta_ref": th, "h0": th + e + rng.normal(0, noise, n) + 0.7}
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    edges = [a0 % (2 * np.pi), (a0 + width) % (2 * np.pi)]
    return Recording("multihead", meta, cols), dict(angles_rad=edges, size_rad=size)


def part_turn_record(rng, t, th, alpha, err, noise: float):
    """One forward run of heads at ``alpha`` (rad) reading the shaft angle ``th`` (rad, per
    row ``t`` s) with the errors ``err`` (rad, rows x heads), white noise ``noise`` (rad) and
    a zero of its own per head; no reference column, a grating of 1000, 4096 or 36000 lines.
    ``rng`` draws the noise, the zeros and the lines in that order (the part-turn records of
    ``tests/test_vibration_doubt.py`` and ``tests/test_change_rival.py``)."""
    import numpy as np

    y = (
        th[:, None]
        + err
        + rng.normal(0, noise, err.shape)
        + rng.uniform(-3, 3, len(alpha))[None, :]
    )
    return heads_recording(rng, t, np.zeros(t.size, int), alpha, y)


def heads_recording(rng, t, run, alpha, y):
    """A multihead ``Recording`` of readings ``y`` (rad, rows x heads) at ``alpha`` (rad),
    times ``t`` (s) and runs ``run``, no reference column; ``rng`` draws its grating (1000,
    4096 or 36000 lines), the last draw of the records built on it."""
    import numpy as np

    from encdesign import Recording

    cols = {"t": t, "run": run}
    for k in range(len(alpha)):
        cols[f"h{k}"] = y[:, k]
    enc = {
        "head_angles_deg": [float(np.degrees(a)) for a in alpha],
        "optical_radius_m": 0.03,
        "grating_lines": int(rng.choice([1000, 4096, 36000])),
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


def quantized_line_record(
    seed: int,
    counts: int,
    periods: int,
    line: float = 0.0,
    phase_rad: float = 0.0,
    delay_s: float = 0.0,
    blur: float = 0.05,
    n_per_run: int = 1200,
):
    """One sensor against a reference, read on a lattice of ``counts`` per turn (LSB
    ``q = 2 pi / counts``), ``periods`` signal periods per turn, two runs at 0.8 and 1.3
    rev/s, each 3 turns forward and back (evenly sampled), a sensor error function of orders
    1-4 (5-20 LSB), noise of ``blur`` LSB ahead of the quantizer and a reading delay
    ``delay_s`` (s, a time shift). ``line``: a static error at shaft order ``counts`` (the
    staircase's fundamental) of ``line`` times the fundamental's own size ``q / pi``, at
    ``phase_rad`` from it (0: in phase, adding to it; an interpolation error there, made
    additively so that its size is free). Returns the recording and ``q``."""
    import numpy as np

    from encdesign import Recording

    rng = np.random.default_rng([seed, 44, 7])
    q = 2 * np.pi / counts
    ts, ths, xs, runs = [], [], [], []
    amps = q * rng.uniform(5, 20, 4) / np.arange(1, 5)
    phs = rng.uniform(0, 2 * np.pi, 4)
    zero = rng.uniform(-3, 3)
    for r, v in enumerate((0.8, 1.3)):
        w = 2 * np.pi * v
        dur = 2 * 3.0 / v
        t = np.arange(n_per_run) * dur / n_per_run
        th0 = rng.uniform(0, 2 * np.pi)

        def path(tt, th0=th0, w=w, dur=dur):
            return th0 + w * np.minimum(tt, dur - tt)

        th = path(t)
        th_s = path(t - delay_s)  # what the sensor saw, delay_s ago
        e = sum(a * np.sin(m * th_s + p) for m, a, p in zip(range(1, 5), amps, phs))
        # the staircase's fundamental is -(q / pi) sin(counts x): the line at phase_rad from it
        e = e - line * (q / np.pi) * np.sin(counts * (th_s + e + zero) + phase_rad)
        x = th_s + e + zero + rng.normal(0, blur * q, t.size)
        ts.append(t + r * (dur + 2.0))
        ths.append(th)
        xs.append(q * np.round(x / q))
        runs.append(np.full(t.size, r))
    cols = {
        "t": np.concatenate(ts),
        "run": np.concatenate(runs),
        "theta_ref": np.concatenate(ths),
        "h0": np.concatenate(xs),
    }
    enc = {"head_angles_deg": [0.0], "sensor": "resolver", "signal_periods_per_rev": periods}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), q


def concealed_sds_layout(tmp_path, seed: int, g: int, layout: dict, effect: str, **extra):
    """Record ``g`` of seed ``seed`` in ``layout`` (the keywords of ``write_concealed_sds``):
    key ``seed * 1000 + g``, a motor speed offset of +-(1e-5 … 1e-3) drawn from
    ``[seed, g, 44]`` where the layout unlocks the clock (``unlocked``)."""
    import jax
    import numpy as np

    from encdesign.simulate import write_concealed_sds

    kw = dict(layout) | extra
    rng = np.random.default_rng([seed, g, 44])
    off = float(rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-5, -3))
    unlocked = kw.pop("unlocked", False)
    return write_concealed_sds(
        tmp_path / f"r{seed}_{g}.toml",
        key=jax.random.key(seed * 1000 + g),
        effect=effect,
        speed_offset=off if unlocked else 0.0,
        **kw,
    )


WHERE = ("pause", "run_start", "inside")
"""Where :func:`shift_arcs_record` puts the change."""


def disk_order_error(rng, th, alpha, M: int, amp0: float):
    """A disk's error at orders 1..M seen by heads at azimuths ``alpha`` (rad) on the shaft
    angle ``th`` (rad): order m at amplitude ``amp0 / m**u`` (u drawn in [0.5, 1.5]) and a
    drawn phase, the draws in the order the part-turn generators have always made them.
    Returns an array (rows, heads) in rad."""
    import numpy as np

    err = np.zeros((th.size, alpha.size))
    for m in range(1, M + 1):
        a = amp0 / m ** rng.uniform(0.5, 1.5)
        err += a * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6.3))
    return err


def shift_arcs_record(rng, where: str) -> tuple:
    """2-3 runs of part of a turn each (0.3-0.9 turns, forward or forward and back, each
    from its own angle), one clock with pauses of 1-3 s, 2-4 heads without a reference,
    300-900 rows per run at 30-1000 Hz, disk orders 1..M (M 3-16) of 3-300x the noise, and
    an eccentricity shift of 10-15x the noise at a time drawn in a pause between runs, at
    the first row of a run after the first, or inside a run (``where``, one of
    :data:`WHERE`). Returns the record and the truth (``change``, ``t_s``, ``run``: in a
    pause the earlier run's; ``run_zeros_rad``: each later run's angle zero of the head-mean
    shaft angle, wrapped to (-pi, pi]; ``theta_rad``, ``err_rad``: the shaft angle and the
    disk error with the shift, per row and head; issue 44 C, ``tests/test_order_step_part_turn.py``,
    ``benchmarks/change_coverage.py``)."""
    import numpy as np

    H = int(rng.integers(2, 5))
    R = int(rng.integers(2, 4))
    nr = int(rng.integers(300, 901))
    rate = float(10 ** rng.uniform(1.5, 3.0))
    noise = float(10 ** rng.uniform(-7.3, -5.5))
    turns = float(rng.uniform(0.3, 0.9))
    both = bool(rng.random() < 0.4)
    pauses = rng.uniform(1.0, 3.0, R - 1)
    ts, ths, runs, t0 = [], [], [], 0.0
    for r in range(R):
        u = np.arange(nr) / rate
        if both:
            half = nr // 2
            th = turns * 2 * np.pi * np.where(np.arange(nr) < half, u / u[half], 2 - u / u[half])
        else:
            th = turns * 2 * np.pi * u / u[-1]
        ths.append(th + rng.uniform(0, 2 * np.pi))
        ts.append(t0 + u)
        runs.append(np.full(nr, r))
        t0 = t0 + u[-1] + (pauses[r] if r < R - 1 else 0.0)
    t, th, run = np.concatenate(ts), np.concatenate(ths), np.concatenate(runs)
    j = int(rng.integers(0, R - 1))  # the pause after run j, or the start of run j + 1
    if where == "pause":
        t_s = float(ts[j][-1] + rng.uniform(0.1, 0.9) * pauses[j])
        truth_run = j
    elif where == "run_start":
        t_s = float(ts[j + 1][0])
        truth_run = j + 1
    else:
        k = int(rng.integers(0, R))
        t_s = float(ts[k][int(rng.uniform(0.3, 0.7) * nr)])
        truth_run = k
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.3, 6.0, H - 1))])
    M = int(rng.integers(3, 17))
    err = disk_order_error(rng, th, alpha, M, noise * 10 ** rng.uniform(0.5, 2.5))
    A = float(rng.uniform(10, 15)) * noise
    err += (t >= t_s)[:, None] * A * np.sin(th[:, None] - alpha[None, :] + rng.uniform(0, 6.3))
    eps = rng.normal(0, noise, err.shape)
    c = rng.uniform(-3, 3, (R, H))  # each run's head constants (rad)
    y = th[:, None] + err + eps + c[run]
    rec = heads_recording(rng, t, run, alpha, y)
    # the runs' angle zeros of the head-mean shaft angle (the base's run_angle_offset_rad)
    zeros = (c.mean(1)[0] - c.mean(1)[1:] + np.pi) % (2 * np.pi) - np.pi
    truth = dict(change="ecc_shift", t_s=t_s, run=truth_run, where=where, run_zeros_rad=zeros)
    truth.update(theta_rad=th, err_rad=err)
    desc = dict(H=H, R=R, nr=nr, turns=round(turns, 2), both=both, M=M, noise=noise)
    return rec, {**truth, "desc": desc}


def env_without_device_count(**extra: str) -> dict[str, str]:
    """This process's environment for a child that picks its own CPU device count: the
    ``--xla_force_host_platform_device_count`` flag left out of ``XLA_FLAGS``, the other XLA
    flags kept (``make test`` compiles at ``--xla_backend_optimization_level=0``; a child
    compiled otherwise could differ in the last bits from the values it is compared with),
    then ``extra`` (an ``XLA_FLAGS`` there is added to the kept flags)."""
    import os

    env = dict(os.environ)
    flags = [f for f in env.pop("XLA_FLAGS", "").split() if "device_count" not in f]
    flags += extra.pop("XLA_FLAGS", "").split()
    return env | ({"XLA_FLAGS": " ".join(flags)} if flags else {}) | extra


def spinning_heads_base(rng, H: int, R: int, n: int, rate_hz: float, noise: float) -> tuple:
    """``(t, run, th, alpha, err)`` of a multihead record's base: ``R`` runs of ``n`` rows at
    ``rate_hz`` (s, each run's clock from 0), the shaft at 0.8-1.8 rev/s from a random angle
    (rad), ``H`` heads (the first at 0, the others sorted in 0.5-5.8 rad) and disk errors at
    orders 1-5 of ``8 * noise / m`` (rad) with random phases; drawn from ``rng`` in that order
    (the generators of ``tests/test_time_located_shape`` and ``tests/test_order_step_head``)."""
    import numpy as np

    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.5, 5.8, H - 1))])
    t = np.tile(np.arange(n) / rate_hz, R)
    run = np.repeat(np.arange(R), n)
    th = np.concatenate(
        [
            2 * np.pi * rng.uniform(0.8, 1.8) * np.arange(n) / rate_hz + rng.uniform(0, 6.28)
            for _ in range(R)
        ]
    )
    err = np.zeros((t.size, H))
    for m in range(1, 6):
        err += 8 * noise / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6.28))
    return t, run, th, alpha, err


def time_view_findings(rec) -> tuple[dict, list[dict]]:
    """``(doc, found)``: the diagnosis document of ``rec`` (validated against the schema) and
    its ``time`` view findings, before the candidates and left ``unexplained``."""
    from encdesign.diagnose._dispatch import diagnose

    doc = diagnose(rec).doc
    validate_diagnosis(doc)
    found = [
        f
        for key in ("findings_before", "unexplained")
        for f in doc.get(key) or []
        if f.get("view") == "time"
    ]
    return doc, found


def reduce_test_record(
    rng, n_per_run: int, fs: float, heads: int, amp: dict, phase: dict, vib=None
):
    """A long multihead record for the block-mean reduction's tests (issue 43): ``heads`` heads
    and ``theta_ref``, 3 runs at 2, 2.5, 3 rev/s sampled at ``fs`` Hz, a disk error of orders
    ``amp`` (rad) at phases ``phase`` (rad), 0.5 urad noise; ``vib`` (rad, or None for none
    and no random draw) a 31 Hz vibration at a random phase per run."""
    import numpy as np

    from encdesign.io._recording import Recording

    alpha = np.array([0.0, 2.1, 4.2, 0.9][:heads])
    cols: dict[str, list] = {"t": [], "run": [], "theta_ref": []}
    cols.update({f"h{k}": [] for k in range(heads)})
    for r in range(3):
        t = np.arange(n_per_run) / fs
        th = 2 * np.pi * (2.0 + 0.5 * r) * t + rng.uniform(0, 6)
        cols["t"].append(t)
        cols["run"].append(np.full(n_per_run, r))
        cols["theta_ref"].append(th + rng.uniform(-1, 1))
        for k in range(heads):
            e = sum(a * np.sin(m * (th - alpha[k]) + phase[m]) for m, a in amp.items())
            if vib is not None:
                e = e + vib * np.sin(2 * np.pi * 31.0 * t + rng.uniform(0, 6))
            cols[f"h{k}"].append(th + e + rng.normal(0, 5e-7, n_per_run) + rng.uniform(-2, 2))
    enc = {"head_angles_deg": np.degrees(alpha).tolist(), "signal_periods_per_rev": 2048}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, {k: np.concatenate(v) for k, v in cols.items()})


# --- one diagnosis per test process (CI time) ---
_SHARED_DIAGNOSES: dict = {}


def _record_digest(rec) -> str:
    """A digest of everything of ``rec`` a diagnosis reads: kind, metadata, path and every
    column's name, dtype and bytes."""
    import hashlib
    import json

    import numpy as np

    h = hashlib.sha256(repr((rec.kind, str(rec.path))).encode())
    h.update(json.dumps(rec.meta, sort_keys=True, default=repr).encode())
    for name in sorted(rec.columns):
        col = np.ascontiguousarray(np.asarray(rec.columns[name]))
        h.update(repr((name, col.dtype.str, col.shape)).encode())
        h.update(col.tobytes())
    return h.hexdigest()


def shared_diagnosis(rec, **kw):
    """``diagnose(rec, **kw)`` computed once per test process for each record and arguments
    (keyword arguments whose values compare by value: ``settings``, ``max_order``): tests of
    one file or of several that diagnose the same record share one diagnosis. The record is
    known by its content (:func:`_record_digest`), never by the test that made it; each call
    gets its own deep copy, which the test may change. One store per process, whether a test
    file imports these helpers as ``helpers`` or as ``tests.helpers`` (two module objects)."""
    import copy

    from encdesign.diagnose import diagnose
    from tests import helpers

    store = helpers._SHARED_DIAGNOSES
    key = (_record_digest(rec), tuple(sorted(kw.items())))
    if key not in store:
        store[key] = diagnose(rec, **kw)
    return copy.deepcopy(store[key])


def count_passes(monkeypatch) -> list[int]:
    """Patch the engine's :func:`._stats_pass.run_passes` to record, per pass, how many of its
    requests needed the rows (a request already done is answered without them)."""
    from encdesign.diagnose.engine import _stats_pass

    passes: list[int] = []
    run = _stats_pass.run_passes

    def counted(reqs):
        passes.append(sum(s.done is None for s in reqs))
        return run(reqs)

    monkeypatch.setattr(_stats_pass, "run_passes", counted)
    return passes


def sweep(cases, keep) -> list:
    """``cases`` as ``pytest.param``\\ s for ``pytest.mark.parametrize``, those in ``keep``
    plain and every other one marked ``sweep`` (docs/DEVELOPING.md, "Test tiers"): ``make
    test`` (so CI) runs the kept cases, ``make test-sweeps`` the rest. A case is one value,
    or a tuple of the arguments of a multi-argument parametrize (then spread); a case already
    a ``pytest.param`` keeps its own marks and id (``keep`` names it by its value, or the
    tuple of its values). An entry of ``keep`` that is not a case raises ``ValueError``
    rather than silently running nothing."""
    import pytest

    def _parts(c):
        if hasattr(c, "values") and hasattr(c, "marks"):
            return tuple(c.values), list(c.marks), c.id
        return (c if isinstance(c, tuple) else (c,)), [], None

    def _key(values):
        return values[0] if len(values) == 1 else values

    cases = [_parts(c) for c in cases]
    known = [_key(v) for v, _, _ in cases]
    missing = [k for k in keep if k not in known]
    if missing:
        raise ValueError(f"sweep: kept cases {missing!r} are not among the cases {known!r}")
    out = []
    for values, marks, id_ in cases:
        extra = [] if _key(values) in keep else [pytest.mark.sweep]
        out.append(pytest.param(*values, marks=marks + extra, id=id_))
    return out
