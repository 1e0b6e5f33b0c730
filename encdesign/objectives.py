"""Objective and constraint functions for encoder design: the public face of
:mod:`encdesign.design._objectives` (``from encdesign.objectives import ...`` keeps working).

See that module for the Monte Carlo build pipeline; all values are SI (rad, m).
"""

from .design._objectives import (
    PROBLEM_OBJECTIVES as PROBLEM_OBJECTIVES,
)
from .design._objectives import (
    TOLERANCE_NAMES as TOLERANCE_NAMES,
)
from .design._objectives import (
    TOLERANCE_UNITS as TOLERANCE_UNITS,
)
from .design._objectives import (
    EncoderDesign as EncoderDesign,
)
from .design._objectives import (
    LayoutDesign as LayoutDesign,
)
from .design._objectives import (
    SDSTolerances as SDSTolerances,
)
from .design._objectives import (
    Tolerances as Tolerances,
)
from .design._objectives import (
    build_metric as build_metric,
)
from .design._objectives import (
    build_metrics as build_metrics,
)
from .design._objectives import (
    build_model as build_model,
)
from .design._objectives import (
    build_residual as build_residual,
)
from .design._objectives import (
    build_yield as build_yield,
)
from .design._objectives import (
    calibration_noise_ms as calibration_noise_ms,
)
from .design._objectives import (
    cotangent_sensitivity as cotangent_sensitivity,
)
from .design._objectives import (
    expected_sensitivity as expected_sensitivity,
)
from .design._objectives import (
    layout_metric as layout_metric,
)
from .design._objectives import (
    layout_metrics as layout_metrics,
)
from .design._objectives import (
    layout_noise_ms as layout_noise_ms,
)
from .design._objectives import (
    layout_residual as layout_residual,
)
from .design._objectives import (
    n_build_normals as n_build_normals,
)
from .design._objectives import (
    residual_peak as residual_peak,
)
from .design._objectives import (
    residual_percentile as residual_percentile,
)
from .design._objectives import (
    residual_rms as residual_rms,
)
from .design._objectives import (
    sds_design as sds_design,
)
from .design._objectives import (
    sds_residuals as sds_residuals,
)
from .design._objectives import (
    smooth_yield as smooth_yield,
)
from .design._objectives import (
    symmetric_angles as symmetric_angles,
)
from .design._objectives import (
    tolerance_cost as tolerance_cost,
)

__all__ = [
    "TOLERANCE_NAMES",
    "TOLERANCE_UNITS",
    "Tolerances",
    "EncoderDesign",
    "symmetric_angles",
    "cotangent_sensitivity",
    "expected_sensitivity",
    "n_build_normals",
    "build_model",
    "build_residual",
    "residual_rms",
    "residual_peak",
    "calibration_noise_ms",
    "build_metric",
    "build_metrics",
    "residual_percentile",
    "build_yield",
    "smooth_yield",
    "tolerance_cost",
    "SDSTolerances",
    "sds_design",
    "sds_residuals",
    "LayoutDesign",
    "layout_residual",
    "layout_noise_ms",
    "layout_metric",
    "layout_metrics",
    "PROBLEM_OBJECTIVES",
]
