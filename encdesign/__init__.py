"""encdesign: differentiable design, optimisation and diagnosis of precision angular encoders.

All quantities are SI (metres, seconds, radians) unless a name says otherwise (``_deg``,
``_urad``, ``_arcsec``). float64 is switched on at import: micro-radian effects on top of
radian-sized angles need it.

The top level holds the names most users need, grouped by concept (:data:`__all__`, at most
70); everything else is public in its subpackage (``docs/DEVELOPING.md``):
``encdesign.physics`` (the models), ``encdesign.io`` (files, study plumbing),
``encdesign.design`` (design files, problems, drivers, tolerances), ``encdesign.diagnose``
(the finder; the subpackage, its entry point is ``encdesign.diagnose.diagnose``),
``encdesign.calibrate`` (calibration) and ``encdesign.simulate`` (bench simulators).
"""

from typing import TYPE_CHECKING as _TYPE_CHECKING

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from . import _cpu as _cpu
from ._lazy import lazy_exports as _lazy_exports

_cpu.configure()  # one CPU device per core unless the user chose (docs/scale.md)

# --- errors: one root for everything encdesign raises
from ._errors import (
    DiagnosisError as DiagnosisError,
    DistributedError as DistributedError,
    EncdesignError as EncdesignError,
    EncdesignInputError as EncdesignInputError,
    OptimisationError as OptimisationError,
)


# The names below are imported when first used (``_lazy``): ``import encdesign`` costs JAX
# and the configuration above, not every subpackage's dependencies (the design drivers'
# optimisers, the simulators, ...); a command such as ``encdesign diagnose`` imports only
# what it runs (docs/scale.md, "Start"). ``from encdesign import X``, ``encdesign.X`` and
# ``dir(encdesign)`` work as before. This block is the list (type checkers read it too).
if _TYPE_CHECKING:
    # --- recordings (files of every kind)
    from .io import (
        Recording as Recording,
        load_recording as load_recording,
        write_recording as write_recording,
    )

    # --- the multihead encoder: kinematic model of read heads on a grating disk
    from .physics import (
        Disk as Disk,
        EncoderModel as EncoderModel,
        Heads as Heads,
        Motion as Motion,
        head_errors as head_errors,
        head_readings as head_readings,
        make_model as make_model,
        noisy_head_readings as noisy_head_readings,
    )

    # --- self-compensation and the encoder theorem
    from .physics import (
        EncoderMap as EncoderMap,
        SelfCompensation as SelfCompensation,
        apply_map as apply_map,
        cotangent_sensitivity as cotangent_sensitivity,
        encoder_map as encoder_map,
        self_compensate as self_compensate,
        surviving_orders as surviving_orders,
    )

    # --- the shifted-delta-sum (SDS) timing instrument
    from .physics import (
        DiskMarks as DiskMarks,
        Motor as Motor,
        SDSDesign as SDSDesign,
        SDSErrors as SDSErrors,
        edge_times as edge_times,
        reference_design as reference_design,
        reference_errors as reference_errors,
        sds_from_edges as sds_from_edges,
        sds_phi_error as sds_phi_error,
        simulate_readings as simulate_readings,
    )

    # --- quadrature signals and vibration
    from .physics import (
        EllipseParams as EllipseParams,
        SignalErrors as SignalErrors,
        Vibration as Vibration,
        fit_ellipse as fit_ellipse,
        phase_error_exact_rad as phase_error_exact_rad,
        quadrature_signals as quadrature_signals,
        synthesize_signals as synthesize_signals,
    )

    # --- design files and bench simulation
    from .design import (
        Design as Design,
        load_design as load_design,
    )
    from .simulate import (
        simulate_recording as simulate_recording,
        simulate_sds_recording as simulate_sds_recording,
    )

    # --- design problems, drivers and tolerances
    from .design import (
        BFGS as BFGS,
        EncoderDesign as EncoderDesign,
        MonteCarloResult as MonteCarloResult,
        Problem as Problem,
        ProblemResult as ProblemResult,
        Solution as Solution,
        Tolerances as Tolerances,
        allocate as allocate,
        check_gradients as check_gradients,
        check_yield as check_yield,
        load_problem as load_problem,
        monte_carlo as monte_carlo,
        objective_function as objective_function,
        optimise as optimise,
        solve_problem as solve_problem,
        sweep_problem as sweep_problem,
        variable as variable,
    )

    # --- diagnosis (the discrepancy finder): ``encdesign.diagnose`` is the subpackage
    from . import diagnose as diagnose
    from .diagnose import (
        Candidate as Candidate,
        Diagnosis as Diagnosis,
        diagnosis_report_text as diagnosis_report_text,
        sds_readings_from_recording as sds_readings_from_recording,
    )

    # --- calibration
    from .calibrate import (
        CalibrationCurve as CalibrationCurve,
        ClosureResult as ClosureResult,
        fit_curve as fit_curve,
        reference_map as reference_map,
        solve_closure as solve_closure,
    )

    # --- the other subpackages, reachable as attributes (``encdesign.physics.mark_angles``)
    from . import calibrate as calibrate
    from . import design as design
    from . import io as io
    from . import physics as physics
    from . import simulate as simulate

__getattr__, __dir__ = _lazy_exports(__name__, __file__)

__all__ = [
    # errors
    "EncdesignError",
    "EncdesignInputError",
    "OptimisationError",
    "DistributedError",
    "DiagnosisError",
    # recordings
    "Recording",
    "load_recording",
    "write_recording",
    # the multihead encoder
    "Disk",
    "Heads",
    "Motion",
    "EncoderModel",
    "make_model",
    "head_errors",
    "head_readings",
    "noisy_head_readings",
    # self-compensation and the encoder theorem
    "SelfCompensation",
    "self_compensate",
    "cotangent_sensitivity",
    "EncoderMap",
    "encoder_map",
    "apply_map",
    "surviving_orders",
    # the SDS instrument
    "SDSDesign",
    "SDSErrors",
    "Motor",
    "DiskMarks",
    "reference_design",
    "reference_errors",
    "edge_times",
    "sds_from_edges",
    "simulate_readings",
    "sds_phi_error",
    "sds_readings_from_recording",
    # quadrature signals and vibration
    "SignalErrors",
    "quadrature_signals",
    "synthesize_signals",
    "fit_ellipse",
    "EllipseParams",
    "phase_error_exact_rad",
    "Vibration",
    # design files and bench simulation
    "Design",
    "load_design",
    "simulate_recording",
    "simulate_sds_recording",
    # design problems, drivers and tolerances
    "Problem",
    "load_problem",
    "solve_problem",
    "sweep_problem",
    "ProblemResult",
    "check_gradients",
    "optimise",
    "BFGS",
    "Solution",
    "monte_carlo",
    "MonteCarloResult",
    "EncoderDesign",
    "Tolerances",
    "allocate",
    "check_yield",
    "objective_function",
    "variable",
    # diagnosis
    "Candidate",
    "Diagnosis",
    "diagnosis_report_text",
    # calibration
    "solve_closure",
    "ClosureResult",
    "fit_curve",
    "CalibrationCurve",
    "reference_map",
]

__version__ = "0.1.0"
