"""The physics of encoders: kinematics of heads on a grating disk, the encoder theorem,
self-compensation, the shifted-delta-sum timing instrument (marks, motor, error sources) and
the quadrature signal layer. Pure JAX models; imports nothing above itself. SI units.
"""

from typing import TYPE_CHECKING as _TYPE_CHECKING

from .._lazy import lazy_exports as _lazy_exports

# Imported on first use (``encdesign._lazy``): a diagnosis needs the effect catalog, not the
# ellipse fit or the SDS instrument. This block is the list (type checkers read it too).
if _TYPE_CHECKING:
    from ._ellipse import (
        EllipseFit as EllipseFit,
    )
    from ._ellipse import (
        EllipseParams as EllipseParams,
    )
    from ._ellipse import (
        VibrationLUT as VibrationLUT,
    )
    from ._ellipse import (
        build_vibration_lut as build_vibration_lut,
    )
    from ._ellipse import (
        compensation_signal_m as compensation_signal_m,
    )
    from ._ellipse import (
        correct_signals as correct_signals,
    )
    from ._ellipse import (
        corrected_phase_rad as corrected_phase_rad,
    )
    from ._ellipse import (
        fit_ellipse as fit_ellipse,
    )
    from ._ellipse import (
        position_from_signals_m as position_from_signals_m,
    )
    from ._ellipse import (
        seed_eq7_choice as seed_eq7_choice,
    )
    from ._ellipse import (
        vibration_compensation_m as vibration_compensation_m,
    )
    from ._kinematics import (
        Disk as Disk,
    )
    from ._kinematics import (
        EncoderModel as EncoderModel,
    )
    from ._kinematics import (
        Heads as Heads,
    )
    from ._kinematics import (
        Motion as Motion,
    )
    from ._kinematics import (
        head_errors as head_errors,
    )
    from ._kinematics import (
        head_errors_batch as head_errors_batch,
    )
    from ._kinematics import (
        head_readings as head_readings,
    )
    from ._kinematics import (
        make_model as make_model,
    )
    from ._kinematics import (
        noisy_head_readings as noisy_head_readings,
    )
    from ._kinematics import (
        stack_models as stack_models,
    )
    from ._layout import (
        LayoutCompensation as LayoutCompensation,
    )
    from ._layout import (
        check_layout as check_layout,
    )
    from ._layout import (
        layout_gain as layout_gain,
    )
    from ._layout import (
        layout_map as layout_map,
    )
    from ._layout import (
        layout_noise_amplification as layout_noise_amplification,
    )
    from ._layout import (
        layout_phases as layout_phases,
    )
    from ._layout import (
        least_squares_compensate as least_squares_compensate,
    )
    from ._layout import (
        unobservable_orders as unobservable_orders,
    )
    from ._motor import (
        Motor as Motor,
    )
    from ._motor import (
        motor_order_sources as motor_order_sources,
    )
    from ._motor import (
        motor_orders as motor_orders,
    )
    from ._motor import (
        time_at_angle as time_at_angle,
    )
    from ._quadrature import (
        Eq4Terms as Eq4Terms,
    )
    from ._quadrature import (
        SignalErrors as SignalErrors,
    )
    from ._quadrature import (
        eq4_terms_m as eq4_terms_m,
    )
    from ._quadrature import (
        error_harmonics as error_harmonics,
    )
    from ._quadrature import (
        interpolation_error_m as interpolation_error_m,
    )
    from ._quadrature import (
        interpolation_error_rad as interpolation_error_rad,
    )
    from ._quadrature import (
        line_period_error as line_period_error,
    )
    from ._quadrature import (
        phase_error_eq4_rad as phase_error_eq4_rad,
    )
    from ._quadrature import (
        phase_error_exact_rad as phase_error_exact_rad,
    )
    from ._quadrature import (
        quadrature_signals as quadrature_signals,
    )
    from ._quadrature import (
        signal_phase_rad as signal_phase_rad,
    )
    from ._quadrature import (
        synthesize_signals as synthesize_signals,
    )
    from ._sds import (
        DiskMarks as DiskMarks,
    )
    from ._sds import (
        SDSDesign as SDSDesign,
    )
    from ._sds import (
        SDSReadings as SDSReadings,
    )
    from ._sds import (
        edge_times as edge_times,
    )
    from ._sds import (
        equally_spaced as equally_spaced,
    )
    from ._sds import (
        mark_angles as mark_angles,
    )
    from ._sds import (
        moved_sensor_pair_errors as moved_sensor_pair_errors,
    )
    from ._sds import (
        perfect_disk as perfect_disk,
    )
    from ._sds import (
        reference_design as reference_design,
    )
    from ._sds import (
        reference_disk as reference_disk,
    )
    from ._sds import (
        reference_errors as reference_errors,
    )
    from ._sds import (
        reference_motor as reference_motor,
    )
    from ._sds import (
        sds_from_edges as sds_from_edges,
    )
    from ._sds import (
        sds_phi_error as sds_phi_error,
    )
    from ._sds import (
        sds_residual as sds_residual,
    )
    from ._sds import (
        simulate_readings as simulate_readings,
    )
    from ._sds import (
        validate_design as validate_design,
    )
    from ._sds_errors import (
        SDSErrors as SDSErrors,
    )
    from ._sds_errors import (
        axis_tilt_error as axis_tilt_error,
    )
    from ._sds_errors import (
        bearing_noise as bearing_noise,
    )
    from ._sds_prediction import (
        SpeedMarkPrediction as SpeedMarkPrediction,
    )
    from ._sds_prediction import (
        predict_speed_mark_error as predict_speed_mark_error,
    )
    from ._selfcomp import (
        EncoderMap as EncoderMap,
    )
    from ._selfcomp import (
        SelfCompensation as SelfCompensation,
    )
    from ._selfcomp import (
        apply_map as apply_map,
    )
    from ._selfcomp import (
        cotangent_equations as cotangent_equations,
    )
    from ._selfcomp import (
        cotangent_sensitivity as cotangent_sensitivity,
    )
    from ._selfcomp import (
        encoder_map as encoder_map,
    )
    from ._selfcomp import (
        self_compensate as self_compensate,
    )
    from ._theorem import (
        averaged_error as averaged_error,
    )
    from ._theorem import (
        fourier_coefficients as fourier_coefficients,
    )
    from ._theorem import (
        fourier_series as fourier_series,
    )
    from ._theorem import (
        mode_amplitudes as mode_amplitudes,
    )
    from ._theorem import (
        mode_transfer as mode_transfer,
    )
    from ._theorem import (
        model_mode_transfer as model_mode_transfer,
    )
    from ._theorem import (
        surviving_orders as surviving_orders,
    )
    from ._vibration import (
        ExcitationEstimate as ExcitationEstimate,
    )
    from ._vibration import (
        Vibration as Vibration,
    )
    from ._vibration import (
        eq5_signal_terms as eq5_signal_terms,
    )
    from ._vibration import (
        estimate_excitation as estimate_excitation,
    )
    from ._vibration import (
        signal_spectrum as signal_spectrum,
    )
    from ._vibration import (
        vibrating_signals as vibrating_signals,
    )
    from ._vibration import (
        vibration_error_rad as vibration_error_rad,
    )
    from ._sds import (
        bearing_noise_default as bearing_noise_default,
    )
    from ._sds_errors import (
        ARCSEC as ARCSEC,
    )

__getattr__, __dir__ = _lazy_exports(__name__, __file__)
