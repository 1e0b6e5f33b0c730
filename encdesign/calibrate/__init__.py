"""Calibration procedures: dual-closure polygon tests, calibration curves and correction
tables, reference mapping against self-compensation, vibration LUTs from stepped shaker
tests (``docs/calibration.md``).
May import physics and io; never design or diagnose.
"""

from ._closure import (
    ClosureCounts as ClosureCounts,
)
from ._closure import (
    ClosureResult as ClosureResult,
)
from ._closure import (
    closure_counts as closure_counts,
)
from ._closure import (
    closure_from_recording as closure_from_recording,
)
from ._closure import (
    closure_matrix as closure_matrix,
)
from ._closure import (
    closure_null_angles as closure_null_angles,
)
from ._closure import (
    harmonic_amplitudes as harmonic_amplitudes,
)
from ._closure import (
    solve_closure as solve_closure,
)
from ._closure import (
    undetermined_harmonics as undetermined_harmonics,
)
from ._curve import (
    CalibrationCurve as CalibrationCurve,
)
from ._curve import (
    apply_correction_table as apply_correction_table,
)
from ._curve import (
    curve_from_closure as curve_from_closure,
)
from ._curve import (
    curve_from_recording as curve_from_recording,
)
from ._curve import (
    fit_curve as fit_curve,
)
from ._curve import (
    read_correction_table as read_correction_table,
)
from ._curve import (
    write_correction_table as write_correction_table,
)
from ._reference import (
    MapComparison as MapComparison,
)
from ._reference import (
    ReferenceMap as ReferenceMap,
)
from ._reference import (
    compare_maps as compare_maps,
)
from ._reference import (
    compare_maps_on_recording as compare_maps_on_recording,
)
from ._reference import (
    reference_map as reference_map,
)
from ._vibration_lut import (
    AccelerometerLevels as AccelerometerLevels,
)
from ._vibration_lut import (
    CombinedLUT as CombinedLUT,
)
from ._vibration_lut import (
    ShakerSteps as ShakerSteps,
)
from ._vibration_lut import (
    SteppedLUT as SteppedLUT,
)
from ._vibration_lut import (
    accelerometer_levels as accelerometer_levels,
)
from ._vibration_lut import (
    build_stepped_lut as build_stepped_lut,
)
from ._vibration_lut import (
    combine_luts as combine_luts,
)
from ._vibration_lut import (
    mount_relative_displacement_m as mount_relative_displacement_m,
)
