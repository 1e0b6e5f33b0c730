"""encdesign: differentiable design, optimisation and diagnosis of precision angular encoders.

All quantities are SI (metres, seconds, radians) unless a name says otherwise (``_deg``,
``_urad``, ``_arcsec``). float64 is switched on at import: micro-radian effects on top of
radian-sized angles need it.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from . import _cpu as _cpu

_cpu.configure()  # one CPU device per core unless the user chose (docs/scale.md)

from ._errors import EncdesignInputError as EncdesignInputError
from .io import (
    Recording as Recording,
    load_recording as load_recording,
    write_recording as write_recording,
)

# --- kinematics, encoder theorem, self-compensation (issue 2) ---
from .design import (
    BenchRun as BenchRun,
    Design as Design,
    load_design as load_design,
    parse_design as parse_design,
    simulate_bench as simulate_bench,
    simulate_recording as simulate_recording,
)
from .physics import (
    Disk as Disk,
    EncoderModel as EncoderModel,
    Heads as Heads,
    Motion as Motion,
    head_errors as head_errors,
    head_errors_batch as head_errors_batch,
    head_readings as head_readings,
    make_model as make_model,
    noisy_head_readings as noisy_head_readings,
    stack_models as stack_models,
)
from .physics import (
    EncoderMap as EncoderMap,
    SelfCompensation as SelfCompensation,
    apply_map as apply_map,
    cotangent_equations as cotangent_equations,
    cotangent_sensitivity as cotangent_sensitivity,
    encoder_map as encoder_map,
    self_compensate as self_compensate,
)
from .physics import (
    averaged_error as averaged_error,
    fourier_coefficients as fourier_coefficients,
    mode_amplitudes as mode_amplitudes,
    mode_transfer as mode_transfer,
    model_mode_transfer as model_mode_transfer,
    surviving_orders as surviving_orders,
)

# --- shifted-delta-sum timing model (issue 3) ---
from .physics import (
    Motor as Motor,
    motor_order_sources as motor_order_sources,
    motor_orders as motor_orders,
    time_at_angle as time_at_angle,
)
from .physics import (
    DiskMarks as DiskMarks,
    SDSDesign as SDSDesign,
    SDSReadings as SDSReadings,
    edge_times as edge_times,
    equally_spaced as equally_spaced,
    mark_angles as mark_angles,
    perfect_disk as perfect_disk,
    reference_design as reference_design,
    reference_disk as reference_disk,
    reference_errors as reference_errors,
    reference_motor as reference_motor,
    sds_from_edges as sds_from_edges,
    sds_phi_error as sds_phi_error,
    sds_residual as sds_residual,
    simulate_readings as simulate_readings,
    validate_design as validate_design,
)
from .physics import (
    SDSErrors as SDSErrors,
    axis_tilt_error as axis_tilt_error,
    bearing_noise as bearing_noise,
)
from .physics import (
    SpeedMarkPrediction as SpeedMarkPrediction,
    predict_speed_mark_error as predict_speed_mark_error,
)
from .io import (
    SDSRecordingResult as SDSRecordingResult,
    sds_readings_from_recording as sds_readings_from_recording,
    simulate_sds_recording as simulate_sds_recording,
)

# --- quadrature signal layer (issue 6) ---
from .physics import (
    EllipseFit as EllipseFit,
    EllipseParams as EllipseParams,
    VibrationLUT as VibrationLUT,
    build_vibration_lut as build_vibration_lut,
    compensation_signal_m as compensation_signal_m,
    correct_signals as correct_signals,
    corrected_phase_rad as corrected_phase_rad,
    fit_ellipse as fit_ellipse,
    position_from_signals_m as position_from_signals_m,
    seed_eq7_choice as seed_eq7_choice,
    vibration_compensation_m as vibration_compensation_m,
)
from .physics import (
    Eq4Terms as Eq4Terms,
    SignalErrors as SignalErrors,
    eq4_terms_m as eq4_terms_m,
    error_harmonics as error_harmonics,
    interpolation_error_m as interpolation_error_m,
    interpolation_error_rad as interpolation_error_rad,
    line_period_error as line_period_error,
    phase_error_eq4_rad as phase_error_eq4_rad,
    phase_error_exact_rad as phase_error_exact_rad,
    quadrature_signals as quadrature_signals,
    signal_phase_rad as signal_phase_rad,
    synthesize_signals as synthesize_signals,
)
from .physics import (
    ExcitationEstimate as ExcitationEstimate,
    Vibration as Vibration,
    eq5_signal_terms as eq5_signal_terms,
    estimate_excitation as estimate_excitation,
    signal_spectrum as signal_spectrum,
    vibrating_signals as vibrating_signals,
    vibration_error_rad as vibration_error_rad,
)

# --- design optimisation (issue 4) ---
from .design import (
    Case as Case,
    CaseRecorder as CaseRecorder,
    read_cases as read_cases,
    write_cases as write_cases,
)
from .design import (
    DOEResult as DOEResult,
    EnumerationResult as EnumerationResult,
    MonteCarloResult as MonteCarloResult,
    OptimisationError as OptimisationError,
    Solution as Solution,
    doe as doe,
    enumerate_designs as enumerate_designs,
    expected_value as expected_value,
    grid_points as grid_points,
    latin_hypercube as latin_hypercube,
    monte_carlo as monte_carlo,
    optimise as optimise,
)
from .design import (
    Problem as Problem,
    ProblemObjective as ProblemObjective,
    VariableInfo as VariableInfo,
    load_problem as load_problem,
    parse_problem as parse_problem,
)
from .design import (
    ProblemResult as ProblemResult,
    check_gradients as check_gradients,
    solve_problem as solve_problem,
    sweep_problem as sweep_problem,
)
from .design import (
    Allocation as Allocation,
    Contributions as Contributions,
    SweepTable as SweepTable,
    allocate as allocate,
    check_yield as check_yield,
    contributions as contributions,
    sweep_scales as sweep_scales,
    tolerance_cost as tolerance_cost,
)
from .design import (
    EncoderDesign as EncoderDesign,
    Tolerances as Tolerances,
)

# --- free head layouts, user objectives, rare-event yield (issue 14) ---
from .design import (
    LayoutDesign as LayoutDesign,
    RareEventResult as RareEventResult,
    importance_yield as importance_yield,
    layout_metrics as layout_metrics,
    objective_function as objective_function,
    variable as variable,
)
from .physics import (
    least_squares_compensate as least_squares_compensate,
    layout_noise_amplification as layout_noise_amplification,
    unobservable_orders as unobservable_orders,
)

# --- discrepancy finder (issue 5) ---
from .diagnose import (
    simulate_concealed_bench as simulate_concealed_bench,
    write_concealed as write_concealed,
)
from .diagnose import (
    Candidate as Candidate,
    Diagnosis as Diagnosis,
    diagnose as diagnose,
    diagnosis_report_text as diagnosis_report_text,
    write_diagnosis_plots as write_diagnosis_plots,
)

# --- calibration: dual closure, calibration curves, reference mapping (issue 13) ---
from .calibrate import (
    CalibrationCurve as CalibrationCurve,
    ClosureResult as ClosureResult,
    closure_from_recording as closure_from_recording,
    compare_maps as compare_maps,
    compare_maps_on_recording as compare_maps_on_recording,
    fit_curve as fit_curve,
    reference_map as reference_map,
    solve_closure as solve_closure,
    write_correction_table as write_correction_table,
)
from .calibrate import (
    SteppedLUT as SteppedLUT,
    build_stepped_lut as build_stepped_lut,
    combine_luts as combine_luts,
)

__version__ = "0.1.0"
