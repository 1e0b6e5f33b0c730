"""Every decision number of the finder is a :class:`FinderSettings` field (issue 44 G, item 2).

An AST scan of every module under ``encdesign/diagnose/`` collects the numeric literals inside
comparisons (the operands of every ``ast.Compare``, including literals inside arithmetic and
calls there, as in ``x > 0.25 * y``); a literal that is not allow-listed here with a reason
fails the test. Literals in a subscript's index (``x[:, 0] > thr``) are indices and are not
collected. The allow-list holds numerical constants, counts, array shapes, physics and
plotting numbers only: a threshold that decides what the finder reports belongs in
``FinderSettings`` (documented, in the generated table of ``docs/diagnose.md``), not here.

A number can also leave a comparison through a module constant (``if x > LIMIT``): every
module-level constant of ``encdesign/diagnose/`` that is a number (or a tuple of numbers) is
allow-listed in :data:`CONSTANTS` with its reason, or fails the second test.

A cap or a floor is a comparison too: the numeric literals in the arguments of ``min``,
``max``, ``np.clip``, ``np.minimum`` and ``np.maximum`` are collected with those of the
comparisons (guards such as ``max(x, 1e-300)``, block sizes and bounds on the work are
allow-listed with their reason; a cap on what the finder fits or reports is a setting).

A number can also hide in a function's default (``def f(x, test_p=1e-4)``): every numeric
default of a parameter under ``encdesign/diagnose/`` is allow-listed in :data:`DEFAULTS`
with its reason, or fails the third test; a default that mirrors a setting is removed (the
callers pass the setting).
"""

from __future__ import annotations

import ast
from pathlib import Path

DIAGNOSE = Path(__file__).resolve().parent.parent / "encdesign" / "diagnose"

# ---- reasons (one category each) -------------------------------------------------------
SIGN = "0 / 1 / -1: a sign, emptiness, unit or direction test (not a tuned number)"
GUARD = "numerical guard: keeps a division or a log finite (float64 underflow)"
NUMERIC = "numerical tolerance: float64 rounding, a solver's convergence or a rank cut-off"
COUNT = "count: the least rows / values / runs / channels an estimator or a test needs"
DOF = "count: degrees of freedom or columns of a term (2 = a cos / sin pair)"
SHAPE = "array shape, parity or a one-hot / integer index rounded at 0.5"
PHYSICS = "physics or geometry (2 pi, the harmonic 2L, the runout orders 1-3)"
SEARCH = "search: where an optimiser starts or how fine its grid is, not what it accepts"
REPORT = "report: how many alternatives or partners are listed, not a verdict"
PLOT = "plot layout only"
BOUND = "bound on the work (rows, bins, iterations, orders scanned), not a threshold"
MODEL = "size of a start-value or smoothing model (orders, degree), not a threshold"
HALF_BLOCK = (
    "resolution: half a time-view block (1/64 of the run's rows), how well the view locates a "
    "time (with step_change_rows)"
)

UNIVERSAL = {0: SIGN, 1: SIGN, -1: SIGN, 1e-300: GUARD}
"""Allowed in every module."""

ALLOWED: dict[tuple[str, float], str] = {
    # engine
    ("engine/_bounds_sums.py", 1e-10): NUMERIC + " (rank tolerance of the probe's eigenvalues)",
    ("engine/_bounds.py", 1e-12): GUARD + " (a probe the base spans entirely)",
    ("engine/_bounds.py", 2): SHAPE
    + " (the square of the probe's norm; log N of at least two values)",
    ("engine/_discover.py", -2): SHAPE + " (the sentinel line index of the run constants)",
    ("engine/_discover.py", 1e-12): GUARD + " (log of a speed)",
    ("engine/_discover_law.py", 1e-6): NUMERIC + " (rank of two terms' projected Gram: same span; "
    "a direction keeping less of its raw norm is dropped, as in _pinv)",
    ("engine/_views_modulated.py", 1e-9): NUMERIC + " (a singular 2x2 matrix)",
    ("engine/_views_modulated.py", 2): DOF + " (a squared trace)",
    ("engine/_views_modulated.py", 4): COUNT + " (a change with 2 rows on either side)",
    ("engine/_discover_law.py", 1e-12): GUARD + " (log of a speed)",
    ("engine/_discover_lines.py", 1e-12): GUARD + " (log of a speed)",
    ("engine/_discover_ring.py", 1e-12): GUARD + " (the period of a line at 0 Hz)",
    ("engine/_document.py", 2): PHYSICS + " (the scan reaches the second harmonic of the base's "
    "highest order)",
    ("engine/_engine.py", 2): PHYSICS,
    ("engine/_reduce.py", 2): PHYSICS + " (the base grows to twice its order, the views scan twice "
    "the base's order, as in _document.scan_order_of; a block of at least two rows)",
    ("engine/_reduce_stream.py", 2): SHAPE + " (a row's stretch-start flag depends on it and "
    "the two rows before it: the rows of context carried into a row group or a share)",
    ("engine/_decimate.py", 0.5): PHYSICS + " (half the rate: the Nyquist frequency)",
    ("engine/_noise.py", 2): PHYSICS + " (half the rate: the Nyquist frequency)",
    ("engine/_reduce.py", 6.0): NUMERIC + " (the leading order of the Dirichlet kernel, "
    "(B^2 - 1) x^2 / 6: a start the exact check then moves)",
    ("engine/_evidence.py", 2): REPORT + " (at most two confounded partners)",
    ("engine/_evidence.py", 3): REPORT + " (at most three alternatives)",
    ("engine/_normal.py", 1e-200): NUMERIC + " (a zero diagonal of the normal matrix)",
    ("engine/_fit.py", 1e-10): NUMERIC + " (a Jacobian column lost in rounding)",
    ("engine/_fit.py", 1e-7): NUMERIC + " (Levenberg-Marquardt convergence)",
    ("engine/_fit.py", 1e-2): NUMERIC + " (LM convergence: 0.01 of chi-square)",
    ("engine/_fit.py", 1e8): NUMERIC + " (LM damping gives up)",
    ("engine/_fit.py", 2): GUARD + " (of a log2: the smallest chunk)",
    ("engine/_goodness.py", 16): COUNT + " (a block of the goodness-of-fit test)",
    ("engine/_goodness.py", 2): COUNT + " (Bonferroni over the two goodness-of-fit tests)",
    ("engine/_goodness.py", 64): COUNT + " (at least 64 rows per goodness-of-fit block)",
    ("engine/_fit.py", 5): BOUND + " (the smallest chunk: 2^5 rows)",
    ("engine/_fit.py", 10): NUMERIC + " (LM damping divided by 10 on success)",
    ("engine/_fit.py", 1e-9): NUMERIC + " (LM damping floor)",
    ("engine/_html.py", 2): SHAPE,
    ("engine/_html.py", 6): PLOT,
    ("engine/_plots.py", 12): PLOT + " (runs' starts labelled on a figure when at most 12)",
    ("engine/_discover.py", -3): SHAPE + " (the sentinel line index: beyond the lines modelled)",
    ("engine/_discover_lines.py", 1e-06): NUMERIC + " (two line values equal to rounding)",
    ("engine/_discover_lines.py", 2): COUNT + " (rows each side of a step); DOF (cos / sin pair)",
    ("engine/_located.py", 2): COUNT + " (a change searched over at least two rows)",
    ("engine/_located.py", 24): SEARCH
    + " (a profile's best row this far from the start: the scan is repeated around it)",
    ("engine/_html_discovery.py", 3): PLOT,
    ("engine/_html_discovery.py", 100): PLOT,
    ("engine/_html_discovery.py", 1.1): PLOT,
    ("engine/_html_discovery.py", 1e-4): PLOT,
    ("engine/_lattice.py", 2): COUNT,
    ("engine/_noise.py", 3): COUNT,
    ("engine/_noise.py", 4): COUNT,
    ("engine/_noise.py", 8): COUNT,
    ("engine/_noise.py", 16): COUNT,
    ("engine/_nuisances.py", 2): COUNT + "; 2 pi",
    ("engine/_nuisances.py", 3): NUMERIC + " (three sample spacings: the angle resolution of "
    "the record)",
    ("engine/_nuisances.py", 64): HALF_BLOCK,
    ("engine/_prepare.py", 2): COUNT + "; half a window; two channels of a quadrature pair",
    ("engine/_prepare.py", 3): COUNT + "; 3.0 in the sum of squares h(h+1)(2h+1)/3",
    ("engine/_prepare.py", 8): COUNT,
    ("engine/_prepare.py", 16): COUNT,
    ("engine/_prepare.py", 5): COUNT + " (the least rows of a speed window)",
    ("engine/_prepare.py", 4): BOUND + " (a speed window is at most a quarter of the run)",
    ("engine/_prepare.py", 0.95): "estimator: the mean square of the smallest 95 % of the "
    "second differences (a reversal or a glitch does not count), a definition of the scatter",
    ("engine/_prepare.py", 2001): BOUND + " (rows of a speed window)",
    ("engine/_prepare.py", 64): BOUND + " (blocks of the held-out folds)",
    ("engine/_results.py", 2): SHAPE + " (a pair)",
    ("engine/_results.py", 1e-12): NUMERIC + " (a correlation <= 1 up to rounding)",
    ("engine/_select.py", 2): SHAPE + " (a squared correlation)",
    ("engine/_settings_check.py", 2): COUNT + " (K-fold needs 2 folds)",
    ("engine/_stepped.py", 8): COUNT + " (the segment finder's own minimum)",
    ("engine/_steps.py", 2): COUNT,
    ("engine/_steps.py", 48): SEARCH + " (rows tried in a step's fine search)",
    ("engine/_steps.py", 64): HALF_BLOCK,
    ("engine/_steps.py", 4): SEARCH + " (four time-view blocks either side of a located step)",
    ("engine/_steps.py", 32): SHAPE + " (the time view's 32 blocks); points of a search grid",
    ("engine/_views.py", 2): COUNT + "; DOF; parity of a run length",
    ("engine/_views.py", 4): COUNT + " (bins of a band)",
    ("engine/_views.py", 1e-9): NUMERIC,
    ("engine/_views.py", 1e-12): NUMERIC + " (nothing left after the run constants); guard",
    ("engine/_views.py", -999.0): REPORT + " (the floor of a reported log10 p)",
    ("engine/_views.py", 1024): BOUND + " (rows per scanned block)",
    ("engine/_views.py", 32): COUNT + " (the time view's blocks, at least 32 rows each)",
    # kinds
    ("kinds/motion/_motion.py", 2.0): PHYSICS + " (Nyquist: half the samples per revolution)",
    ("kinds/motion/_motion.py", 0.5): SHAPE + " (a run's centre and half-span in time)",
    ("kinds/motion/_motion.py", 1e-12): GUARD + " (a zero time span)",
    ("kinds/sds/_sds.py", 2): COUNT + " (a cos / sin pair per test; half the values); guard of a "
    "log",
    ("kinds/multihead/_multihead.py", 2): COUNT + " (two heads or runs); 2 pi",
    ("kinds/multihead/_multihead.py", 4): COUNT,
    ("kinds/multihead/_multihead.py", 1e-12): NUMERIC + " (a step at its own row)",
    ("kinds/multihead/_multihead.py", 16): BOUND + " (2^16 rows per block)",
    ("kinds/multihead/_symmetry.py", 2): COUNT + " (two heads)",
    ("kinds/multihead/_run_align.py", 2): COUNT + " (two runs)",
    ("kinds/multihead/_multihead_terms.py", 2): PHYSICS + "; DOF; a squared trace",
    ("kinds/multihead/_order_step_zeros.py", 2): "counts (several runs, several heads) and a "
    "squared trace (the 2x2 step Gram's singularity test, as _multihead_terms._step_gain)",
    ("kinds/multihead/_order_step_bins.py", 2): DOF + " (order 1's sin and cos beside the run "
    "constants: the view's base without the base's own columns)",
    ("kinds/multihead/_runout.py", 2): PHYSICS + " (a squared amplitude)",
    ("kinds/multihead/_multihead_terms.py", 8): COUNT + " (at least 8 rows per bin)",
    ("kinds/multihead/_order_step_head.py", 2): SHAPE + " (the order-1 pair: sin, cos)",
    ("kinds/multihead/_vibration_doubt.py", 1e-9): GUARD + " (a zero span of revolutions)",
    ("kinds/multihead/_vibration_doubt.py", 2): COUNT + " (two angles make a gap)",
    ("kinds/multihead/_reference_data.py", 2): COUNT,
    ("kinds/multihead/_reference_terms.py", 2): SHAPE,
    ("kinds/multihead/_reference_terms.py", 8): COUNT,
    ("kinds/multihead/_reference_terms.py", 0.5): SHAPE,
    ("kinds/multihead/_reference_terms.py", 1e-9): GUARD + " (a zero time span)",
    ("kinds/quadrature/_quadrature.py", 2): SHAPE + " (the two coordinates of the centre)",
    ("kinds/quadrature/_quadrature.py", 4): SHAPE + " (an order's parity mod 4)",
    ("kinds/quadrature/_quadrature.py", 16): COUNT,
    ("kinds/quadrature/_quadrature.py", 32): COUNT + " (samples for a conic fit)",
    ("kinds/quadrature/_quadrature.py", 3): PHYSICS + " (radial orders from 3: the ellipse "
    "takes 1 and 2)",
    ("kinds/quadrature/_quadrature.py", 8): COUNT + " (8 kept samples per radial order: the "
    "phase is sampled irregularly)",
    ("kinds/sds/_sds_transient.py", 2): COUNT + " (another moving sensor to share a deviation)",
    ("kinds/sds/_sds_data.py", 2): COUNT + " (revolutions per run); two mark periods",
    ("kinds/sds/_sds_data.py", 4): COUNT + " (runs, marks)",
    ("kinds/sds/_sds_data.py", 16): COUNT + " (stamp differences)",
    ("kinds/sds/_sds_data.py", 100): BOUND + " (orders of the readout table)",
    ("kinds/sds/_sds_noise.py", 2): COUNT + "; DOF; a squared norm",
    ("kinds/sds/_sds_common_rules.py", 2): DOF + " (a cos / sin pair; ln of at least 2 values)",
    ("kinds/sds/_sds_common_rules.py", 3): COUNT + " (axes of an array)",
    ("kinds/sds/_sds_drift.py", 2): COUNT + " (ln of at least 2 run means; axes of an array)",
    ("kinds/sds/_sds_noise.py", 3): COUNT + " (degrees of freedom of an F-test)",
    ("kinds/sds/_sds_noise.py", 1e-9): NUMERIC,
    ("kinds/sds/_sds_noise.py", 1e-10): NUMERIC + " (rank cut-off)",
    ("kinds/sds/_sds_noise.py", 1e4): NUMERIC + " (F tends to chi-square: no widening)",
    ("kinds/sds/_sds_noise.py", 4): DOF + " (a rotating and a common cos / sin pair per order)",
    ("kinds/sds/_sds_noise.py", 1e-12): GUARD + " (a zero time span)",
    ("kinds/sds/_sds_pairs.py", 2): COUNT + " (a pair of columns; half the values); a squared norm",
    ("kinds/sds/_sds_pairs.py", 3): COUNT + " (degrees of freedom of an F-test)",
    ("kinds/sds/_sds_pairs.py", 1e-10): NUMERIC + " (a singular pair's Gram determinant)",
    ("kinds/sds/_sds_common_mod.py", 2): DOF
    + " (2 dof of a cos / sin pair; half the runs: the common orders a record resolves;"
    + " a squared trace)",
    ("kinds/sds/_sds_common_mod.py", 4): COUNT + " (a change with 2 runs on either side)",
    ("kinds/sds/_sds_level_out.py", 2): COUNT + " (a pair of columns)",
    ("kinds/sds/_sds_level_out.py", 3): COUNT
    + " (array dimensions; degrees of freedom left for a level, as _sds_pairs' F-test)",
    ("kinds/sds/_sds_level_out.py", 1e-6): NUMERIC
    + " (a direction of the columns the level's basis holds: its singular value off it)",
    ("kinds/sds/_sds_level_out.py", 1e-12): NUMERIC + " (the same cut-off on a squared norm)",
    ("kinds/sds/_sds_level_out.py", 1e-9): NUMERIC
    + " (common_share: the columns' rank, singular values above 1e-9 of the largest)",
    ("kinds/sds/_sds_level_common.py", 1e-10): NUMERIC
    + " (the base's common columns' rank, as _sds_noise.span_basis cuts)",
    ("kinds/sds/_sds_level_common.py", 2): SHAPE + " (the square of a column norm)",
    ("kinds/sds/_sds_level_common.py", 1e-6): NUMERIC
    + " (a direction of the columns' common parts: its singular value, as LevelOut cuts)",
    ("kinds/sds/_sds_level_common.py", 1e-12): NUMERIC + " (the same cut-off on a squared norm)",
    ("kinds/sds/_sds_level_common.py", 3): COUNT
    + " (degrees of freedom left for the common component's level, as LevelOut's)",
    ("kinds/sds/_sds_terms.py", 2): COUNT + " (two sensors)",
    ("kinds/sds/_sds_terms.py", 4): SEARCH
    + " (detection-bound probes: a step's first run at the quartiles of the runs)",
    ("kinds/sds/_sds_terms.py", 3): SEARCH + " (three starts)",
    ("kinds/sds/_sds_terms.py", 0.03): SEARCH + " (distinct start ratios)",
    ("kinds/sds/_sds_terms.py", 0.5): SHAPE,
    ("kinds/sds/_sds_terms.py", 1e-9): NUMERIC,
    ("kinds/sds/_sds_terms.py", 8): SEARCH + " (grid step: an eighth of a turn over the span)",
    ("kinds/sds/_sds_terms.py", 0.01): SEARCH + " (grid step at most 0.01)",
    ("kinds/sds/_sds_terms.py", 1e-15): GUARD,
}
"""``(module under encdesign/diagnose, literal) -> reason``; every entry must be used."""


CONSTANTS: dict[tuple[str, str], str] = {
    ("engine/_rowshare.py", "ROW_GROUPS"): BOUND
    + " (groups a pass's chunks are cut into, shared over processes; fixed so that 1 and N "
    "processes sum in the same order)",
    ("engine/_discover_lines.py", "STEP_BINS"): SEARCH + " (change points a step term scans)",
    ("engine/_discover_lines.py", "STEP_EXACT_ROWS"): BOUND
    + " (rows up to which a step is located with the catalog model projected out)",
    ("engine/_bounds_shares.py", "VIEW_DOUBLINGS"): BOUND
    + " (sizes tried before a view is called blind)",
    ("engine/_spill.py", "TRIAL_STEPS"): BOUND
    + " (Levenberg-Marquardt steps of a fit, as the trial fits of stage 4)",
    ("engine/_bounds.py", "VIEW_BISECTIONS"): BOUND + " (bisections of a bound: 2 %)",
    ("engine/_views_leakage.py", "_GOLDEN_STEPS"): NUMERIC
    + " (golden-section steps of a line's frequency within its bin: 4e-9 bins)",
    ("engine/_bounds.py", "SEEN_RTOL"): NUMERIC + " (rounding of a noncentrality comparison)",
    ("engine/_bounds_shares.py", "SHARE_TOL"): NUMERIC
    + " (the share rules' size: the located excess within 2 %, the size within 1 %)",
    ("engine/_bounds.py", "PROBE_NORM"): NUMERIC
    + " (the probe's whitened norm: the fits are linear in it)",
    ("kinds/multihead/_vibration_doubt.py", "NO_DOUBT"): GUARD
    + " (the margin reported where a vibration doubt rule does not apply: no one speed, no "
    "value lattice; it passes any margin setting)",
    ("kinds/multihead/_vibration_doubt.py", "REFINE_ROUNDS"): NUMERIC
    + " (the line frequency's finer grids in locked_margin)",
    ("kinds/multihead/_multihead_terms.py", "VIBRATION_PROBE_NYQUIST"): SEARCH
    + " (the frequency at which the vibration's detection bound is stated, reported with it)",
    ("kinds/multihead/_multihead_probes.py", "WOBBLE_PROBE_FRACTION"): SEARCH
    + " (the fractional order at which the bearing wobble's detection bound is stated, "
    "reported with it)",
    ("kinds/multihead/_multihead_probes.py", "SHIFT_PROBE_QUANTILES"): SEARCH
    + " (the shift times an eccentricity shift's detection bound is the worst of, stated)",
    ("kinds/sds/_sds_probes.py", "TILT_PROBE_RAD"): NUMERIC
    + " (the small tilt the axis tilt's probe is evaluated at: its error is linear in "
    "beta^2 / 4 there)",
    ("kinds/sds/_sds_probes.py", "WOBBLE_PROBE_RATIO"): SEARCH
    + " (the cage ratio at which a bearing wobble's detection bound is stated, reported)",
    ("engine/_discover.py", "MAX_TERMS"): BOUND + " (terms the forward selection may add)",
    ("engine/_discover_lines.py", "MAX_LINES"): BOUND + " (located lines modelled)",
    ("engine/_discover.py", "MAX_CELLS"): BOUND + " (cells with a modulation of their own)",
    ("engine/_discover_law.py", "BETA_RANGE"): SEARCH + " (speed exponents searched)",
    ("engine/_discover_law.py", "KEEP_SHARE"): NUMERIC + " (a direction the catalog spans)",
    ("engine/_discover_ring.py", "RING_RUNS_MAX"): SEARCH + " (longest decay time searched)",
    ("engine/_discover_ring.py", "RING_PERIODS_MIN"): SEARCH + " (shortest decay time searched)",
    ("engine/_discover_ring.py", "RING_GRID"): SEARCH + " (decay times on the starting grid)",
    ("engine/_discover_ring.py", "XATOL_LOG_T"): NUMERIC + " (the decay time's search tolerance)",
    ("engine/_discover_ring.py", "XATOL_F"): NUMERIC + " (the frequency's search tolerance)",
    ("engine/_document.py", "SWEEP_WINDOW"): BOUND + " (rows of a moving mean)",
    ("engine/_document.py", "LATTICE_ROWS"): BOUND,
    ("engine/_reduce.py", "RATE_OVER_NEEDED"): BOUND
    + " (stage 2's output rate over the highest frequency needed: rows per second kept; the "
    "bound itself is reduce_attenuation_max, checked on the design)",
    ("engine/_reduce.py", "MIN_ROWS_OUT"): BOUND
    + " (stage 2 is not applied where fewer rows would be left)",
    ("engine/_decimate.py", "KAISER_BETA"): NUMERIC
    + " (the FIR design's window; the taps grow until the bound holds)",
    ("engine/_decimate.py", "PC_ERROR_MAX"): NUMERIC
    + " (the design's power complementarity, white noise stays white within it; stated)",
    ("engine/_decimate.py", "TAPS_PER_TRANSITION"): SEARCH + " (the first design's taps)",
    ("engine/_decimate.py", "TAPS_GROWTH"): SEARCH + " (taps of the next design tried)",
    ("engine/_decimate.py", "STOP_CHECK_POINTS"): REPORT
    + " (frequencies on which the stopband's gain is stated)",
    ("engine/_decimate.py", "TAPS_MAX"): BOUND + " (taps of the longest design tried)",
    ("engine/_decimate.py", "CHECK_POINTS"): NUMERIC
    + " (frequencies on which the design's bound is checked)",
    ("engine/_decimate.py", "OUT_CHUNK"): BOUND + " (outputs filtered at a time: memory)",
    ("engine/_noise.py", "NOISE_BAND_MIN_ROWS"): BOUND
    + " (segments shorter add nothing to the decimated record's first noise estimate)",
    ("engine/_reduce.py", "PASS_ROWS"): BOUND + " (rows per slice of the reduction's passes)",
    ("engine/_reduce.py", "GAP_STEPS"): NUMERIC + " (a block is evenly sampled, as the "
    "attenuation bound assumes: one missed sample, a step of 2 intervals, ends a stretch)",
    ("engine/_reduce.py", "SPEED_QUANTILE"): "estimator: the fastest shaft rate as a high "
    "quantile (a glitch cannot set it)",
    ("engine/_html.py", "MAX_POINTS"): PLOT,
    ("engine/_html.py", "MAX_PANELS"): PLOT,
    ("engine/_html_discovery.py", "MAX_SPECTRUM_ORDER"): PLOT,
    ("engine/_html_discovery.py", "FOLD_BINS"): PLOT,
    ("engine/_noise.py", "TRIM_QUANTILE"): "estimator: the trimmed RMS's quantile, with its "
    "consistency factor _TRIM_RMS (a definition of the noise scale, not a threshold)",
    ("engine/_noise.py", "ROBUST_ROWS"): BOUND,
    ("engine/_constants.py", "CHUNK_ROWS"): BOUND,
    ("engine/_constants.py", "CACHE_BYTES"): BOUND,
    ("engine/_constants.py", "FIT_STOP_CHI2"): NUMERIC
    + " (the Levenberg-Marquardt loop's stopping tolerance in chi-square; the selection reads "
    "a difference below it as the fits stopping, not the data)",
    ("engine/_constants.py", "FIT_STOP_REL"): NUMERIC + " (the same tolerance, relative)",
    ("kinds/multihead/_fourier.py", "TRIG_TABLE_ERROR"): NUMERIC
    + " (the angle-addition recurrence's stated rounding bound, in units of m eps: tested)",
    ("engine/_normal.py", "CANCEL_MAX"): NUMERIC
    + " (accumulated normal equations used only while their rounding stays ~2e-12 relative)",
    ("engine/_normal.py", "PIVOT_TIE"): NUMERIC
    + " (pivots within it are ties broken by column order: far above the rounding of sums)",
    ("engine/_constants.py", "D2_VAR"): "estimator: variance of a noise estimator (exact)",
    ("engine/_steps.py", "REFINE_STEP_SHIFTS"): BOUND,
    ("engine/_steps_near.py", "OFF_CHANGE_GRID"): BOUND,
    ("engine/_change_rival.py", "ORDER_STEP_ORDER"): PHYSICS
    + " (the order_step view's order: a disk moved on its hub changes its order 1)",
    ("engine/_views.py", "SCAN_BLOCK"): BOUND,
    ("engine/_views_modulated.py", "BLOCK_VALUES"): BOUND,
    ("engine/_views_orders.py", "SCAN_VALUES"): BOUND + " (rows x orders per block of a pass)",
    ("engine/_views_sums.py", "GEOMETRY_KEPT"): BOUND + " (geometry entries cached)",
    ("kinds/multihead/_order_step_bins.py", "BIN_ROWS"): BOUND + " (rows per block of a pass)",
    ("kinds/multihead/_order_step_head.py", "SINGULAR_RTOL"): NUMERIC
    + " (a head step the base spans to rounding: gain 0)",
    ("kinds/multihead/_order_step_zeros.py", "BLOCK_ROWS"): BOUND + " (rows per block of a pass)",
    ("kinds/multihead/_order_step_zeros.py", "BATCH"): BOUND + " (zero settings per batch)",
    ("kinds/multihead/_multihead.py", "COVERAGE_ORDER_MAX"): BOUND,
    ("kinds/multihead/_multihead.py", "COVERAGE_ROWS"): BOUND,
    ("kinds/multihead/_multihead.py", "SHAFT_ITERATIONS"): BOUND + " (fixed-point passes)",
    ("kinds/multihead/_run_align.py", "ALIGN_GRID"): SEARCH + " (run zeros tried for a start)",
    ("kinds/multihead/_run_align.py", "RUN_NORMAL_ROWS"): BOUND
    + " (rows per block of the runs' normal equations: the items split over the processes)",
    ("kinds/multihead/_runout.py", "SPLIT_ROWS"): BOUND
    + " (rows per block of the vibration start's gains: the items split over the processes)",
    ("kinds/multihead/_runout.py", "RUNOUT_ORDERS"): PHYSICS,
    ("kinds/multihead/_multihead_terms.py", "ORDER_STEP_BINS"): BOUND,
    ("kinds/multihead/_beam_tilt.py", "SPAN_MIN"): NUMERIC + " (a zero pattern vector)",
    ("kinds/multihead/_reference_terms.py", "INTERP_SMOOTH_ORDERS"): MODEL,
    ("kinds/multihead/_reference_terms.py", "QUANT_SMOOTH_ORDERS"): MODEL,
    ("kinds/multihead/_reference_terms.py", "QUANT_POLY_DEGREE"): MODEL,
    ("kinds/multihead/_reference_terms.py", "STAIRCASE_BLURS"): MODEL,
    ("kinds/sds/_sds_noise.py", "REFERENCE_RADIUS_M"): PHYSICS + " (1 inch: a unit of the "
    "reported sizes)",
    ("kinds/sds/_sds_noise.py", "BEAM_ORDERS"): PHYSICS,
}
"""``(module, NAME) -> reason`` for every module-level numeric constant; every entry must be
used."""

ARGUMENT = (
    "a caller's argument (the CLI's --max-effects): how many effects the user asks to be "
    "named at most, not a threshold on what is named"
)

DEFAULTS: dict[tuple[str, str], str] = {
    ("_dispatch.py", "diagnose.max_effects"): ARGUMENT,
    ("engine/_engine.py", "run_engine.max_effects"): ARGUMENT,
    ("engine/_select.py", "select.max_effects"): ARGUMENT,
    ("engine/_discover_lines.py", "_pinv.share"): NUMERIC + " (a pseudo-inverse's rank cut-off)",
    ("engine/_located.py", "scan_indices.near"): SEARCH
    + " (rows scanned one by one around a profile's best, then spaced out)",
    ("engine/_discover_law.py", "_psolve.rtol"): NUMERIC + " (a pseudo-inverse's rank cut-off)",
    ("engine/_normal.py", "_pivoted_rank.tol"): NUMERIC + " (rank cut-off)",
    ("engine/_fit.py", "fit.max_steps"): BOUND + " (Levenberg-Marquardt steps)",
    ("engine/_fit.py", "fit_steps.max_steps"): BOUND + " (the same steps, fit as a generator)",
    ("engine/_fit_memo.py", "remembered_steps.max_steps"): BOUND
    + " (Levenberg-Marquardt steps, as Fitter.fit)",
    ("engine/_fit_memo.py", "remembered_fit.max_steps"): BOUND + " (the same steps)",
    ("engine/_document.py", "_g.digits"): REPORT + " (significant digits printed)",
    ("engine/_html_discovery.py", "order_amplitudes.chunk"): PLOT,
    ("engine/_lattice.py", "_approximate_gcd.max_iter"): BOUND,
    ("engine/_views.py", "view_band.n_bands"): BOUND + " (the band view's frequency bands)",
    ("kinds/multihead/_reference_data.py", "velocity_width_rad_s.fraction"): "physics model: "
    "the smoothing width of a simulated direction sign (a few percent of the speed), for the "
    "generated records of the tests; the finder does not call it",
    ("kinds/multihead/_reference_data.py", "dominant_orders.n"): REPORT + " (orders listed)",
    ("kinds/sds/_sds_data.py", "stamp_lattice.max_samples"): BOUND + " (stamps read)",
    ("kinds/sds/_sds_noise.py", "dof_widening.q"): DOF + " (of the term whose test is widened)",
}
"""``(module, "function.parameter") -> reason`` for every numeric parameter default; every
entry must be used."""


def _number(node: ast.AST) -> float | None:
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        return node.value
    if (
        isinstance(node, ast.UnaryOp)
        and isinstance(node.op, ast.USub)
        and isinstance(node.operand, ast.Constant)
        and type(node.operand.value) in (int, float)
    ):
        return -node.operand.value
    return None


def _literals(node: ast.AST):
    """Numeric literals in an operand, arithmetic and calls included, indices excluded."""
    v = _number(node)
    if v is not None:
        yield node, v
        return
    if isinstance(node, ast.Subscript):
        yield from _literals(node.value)
        return
    for child in ast.iter_child_nodes(node):
        yield from _literals(child)


BOUNDING_CALLS = frozenset({"min", "max", "clip", "minimum", "maximum"})
"""Calls whose numeric arguments are a cap or a floor (``min``, ``np.clip``, ...)."""


def _bounding_call(node: ast.AST) -> bool:
    if not isinstance(node, ast.Call):
        return False
    f = node.func
    name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
    return name in BOUNDING_CALLS


def compared_literals(source: str) -> list[tuple[int, float, str]]:
    """``(line, literal, line text)`` of every numeric literal inside a comparison or an
    argument of a bounding call (:data:`BOUNDING_CALLS`)."""
    lines = source.splitlines()
    out, seen = [], set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
        elif _bounding_call(node):
            operands = [*node.args, *(k.value for k in node.keywords)]
        else:
            continue
        for operand in operands:
            for lit, v in _literals(operand):
                if (lit.lineno, lit.col_offset) not in seen:
                    seen.add((lit.lineno, lit.col_offset))
                    out.append((lit.lineno, v, lines[lit.lineno - 1].strip()))
    return sorted(out)


def scan(root: Path = DIAGNOSE) -> tuple[list[str], set[tuple[str, float]]]:
    """Literals not allow-listed (``module:line: literal: text``) and the entries used."""
    bad, used = [], set()
    for path in sorted(root.rglob("*.py")):
        mod = path.relative_to(root).as_posix()
        for line, v, text in compared_literals(path.read_text(encoding="utf-8")):
            if v in UNIVERSAL:
                continue
            if (mod, v) in ALLOWED:
                used.add((mod, v))
                continue
            bad.append(f"{mod}:{line}: {v!r}: {text}")
    return bad, used


def test_every_decision_number_in_the_diagnose_modules_is_a_setting():
    bad, _ = scan()
    assert not bad, (
        "numeric literals in comparisons under encdesign/diagnose/ that are neither a "
        "FinderSettings field nor allow-listed in tests/test_settings_literals.py (a "
        "threshold that decides a finding: move it into FinderSettings with its docstring "
        "and regenerate docs/diagnose.md's table; a numerical constant or a count: "
        "allow-list it with its reason):\n" + "\n".join(bad)
    )


def test_the_allow_list_has_no_stale_entry():
    _, used = scan()
    stale = sorted(set(ALLOWED) - used)
    assert not stale, f"allow-listed literals no longer found (remove them): {stale}"
    assert all(reason.strip() for reason in ALLOWED.values())


def test_the_scan_finds_a_threshold_inside_arithmetic(tmp_path):
    """The scan can fail: a threshold in arithmetic, a chained comparison and a call in a
    comparison are found; an index, a string and a number outside a comparison are not."""
    src = (
        "def f(pw, x, k):\n"
        "    a = 0.7 * x\n"
        "    if pw[k] >= 0.25 * pw.max():\n"
        "        return x[:, 3] > a\n"
        "    return -0.5 < g(x, 2.5) <= 'a'\n"
    )
    found = [(line, v) for line, v, _ in compared_literals(src)]
    assert found == [(3, 0.25), (5, -0.5), (5, 2.5)]
    capped = (
        "def f(x, n):\n"
        "    k = min(15, 3 + max(0.0, x - 3.5) // 2.0)\n"
        "    return np.clip(x[2], 0.2, n)\n"
    )
    found = [(line, v) for line, v, _ in compared_literals(capped)]
    assert found == [(2, 0.0), (2, 2.0), (2, 3), (2, 3.5), (2, 15), (3, 0.2)]
    pkg = tmp_path / "engine"
    pkg.mkdir()
    (pkg / "_views.py").write_text(src, encoding="utf-8")
    bad, _ = scan(tmp_path)
    assert len(bad) == 3 and bad[0].startswith("engine/_views.py:3: 0.25:")


def _numeric(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return type(node.value) in (int, float)
    if isinstance(node, ast.Tuple | ast.List):
        return bool(node.elts) and all(_numeric(e) for e in node.elts)
    if isinstance(node, ast.UnaryOp):
        return _numeric(node.operand)
    if isinstance(node, ast.BinOp):
        return _numeric(node.left) and _numeric(node.right)
    return False


def numeric_constants(source: str) -> list[tuple[int, str, str]]:
    """``(line, name, value)`` of every module-level constant that is a number, arithmetic
    of numbers or a tuple of numbers."""
    out = []
    for node in ast.parse(source).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target, value = node.targets[0], node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            target, value = node.target, node.value
        else:
            continue
        if isinstance(target, ast.Name) and _numeric(value):
            out.append((node.lineno, target.id, ast.unparse(value)))
    return out


def scan_constants(root: Path = DIAGNOSE) -> tuple[list[str], set[tuple[str, str]]]:
    bad, used = [], set()
    for path in sorted(root.rglob("*.py")):
        mod = path.relative_to(root).as_posix()
        for line, name, value in numeric_constants(path.read_text(encoding="utf-8")):
            if (mod, name) in CONSTANTS:
                used.add((mod, name))
            else:
                bad.append(f"{mod}:{line}: {name} = {value}")
    return bad, used


def test_module_constants_are_not_thresholds():
    """A threshold is not hidden in a module constant: each numeric one has its reason."""
    bad, used = scan_constants()
    assert not bad, (
        "module-level numeric constants under encdesign/diagnose/ not allow-listed in "
        "tests/test_settings_literals.py CONSTANTS (a threshold: make it a FinderSettings "
        "field read through the settings passed in):\n" + "\n".join(bad)
    )
    stale = sorted(set(CONSTANTS) - used)
    assert not stale, f"allow-listed constants no longer found (remove them): {stale}"


def test_the_constant_scan_finds_a_new_constant(tmp_path):
    src = "import math\nLIMIT = 0.25\nPAIR = (1, -2.0)\nNAME = 'x'\nF = math.pi\n"
    assert [n for _, n, _ in numeric_constants(src)] == ["LIMIT", "PAIR"]
    (tmp_path / "_x.py").write_text(src, encoding="utf-8")
    bad, _ = scan_constants(tmp_path)
    assert bad == ["_x.py:2: LIMIT = 0.25", "_x.py:3: PAIR = (1, -2.0)"]


def numeric_defaults(source: str) -> list[tuple[int, str, float]]:
    """``(line, "function.parameter", value)`` of every parameter whose default is a number
    (functions, methods and lambdas at any depth)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            continue
        a = node.args
        pos = [*a.posonlyargs, *a.args]
        pairs = [*zip(pos[len(pos) - len(a.defaults) :], a.defaults)]
        pairs += [(k, d) for k, d in zip(a.kwonlyargs, a.kw_defaults) if d is not None]
        for arg, default in pairs:
            v = _number(default)
            if v is not None:
                out.append((default.lineno, f"{getattr(node, 'name', 'lambda')}.{arg.arg}", v))
    return sorted(out)


def scan_defaults(root: Path = DIAGNOSE) -> tuple[list[str], set[tuple[str, str]]]:
    bad, used = [], set()
    for path in sorted(root.rglob("*.py")):
        mod = path.relative_to(root).as_posix()
        for line, name, v in numeric_defaults(path.read_text(encoding="utf-8")):
            if v in UNIVERSAL:
                continue
            if (mod, name) in DEFAULTS:
                used.add((mod, name))
            else:
                bad.append(f"{mod}:{line}: {name} = {v!r}")
    return bad, used


def test_numeric_defaults_are_not_thresholds():
    """A threshold is not hidden in a parameter's default: each numeric one has its reason,
    and one that mirrors a setting is gone (its callers pass the setting)."""
    bad, used = scan_defaults()
    assert not bad, (
        "numeric parameter defaults under encdesign/diagnose/ not allow-listed in "
        "tests/test_settings_literals.py DEFAULTS (a threshold: make it a FinderSettings field "
        "and a required parameter its callers pass; a size or a count: allow-list it with its "
        "reason):\n" + "\n".join(bad)
    )
    stale = sorted(set(DEFAULTS) - used)
    assert not stale, f"allow-listed defaults no longer found (remove them): {stale}"
    assert all(reason.strip() for reason in DEFAULTS.values())


def test_the_default_scan_finds_a_new_default(tmp_path):
    src = (
        "def f(x, p=1e-4, *, q=-2, name='a', w=None):\n"
        "    return lambda y, k=3: y\n"
        "class A:\n"
        "    def g(self, band=0.002, n=2 * 3):\n"
        "        pass\n"
    )
    assert numeric_defaults(src) == [
        (1, "f.p", 1e-4),
        (1, "f.q", -2),
        (2, "lambda.k", 3),
        (4, "g.band", 0.002),
    ]
    (tmp_path / "_x.py").write_text(src, encoding="utf-8")
    bad, _ = scan_defaults(tmp_path)
    assert bad == [
        "_x.py:1: f.p = 0.0001",
        "_x.py:1: f.q = -2",
        "_x.py:2: lambda.k = 3",
        "_x.py:4: g.band = 0.002",
    ]
