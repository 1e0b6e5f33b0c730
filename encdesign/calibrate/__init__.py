"""Calibration procedures: dual-closure polygon tests, calibration curves and correction
tables, reference mapping against self-compensation (``docs/calibration.md``).
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
    simulate_closure_readings as simulate_closure_readings,
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
