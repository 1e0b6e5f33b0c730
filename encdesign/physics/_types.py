"""Shape-annotated array types of the public physics and design signatures (jaxtyping).

The dimension names are shared across the package, so a static reader (and jaxtyping's
runtime check in the tests, ``docs/DEVELOPING.md``) sees which axes of two arguments must
agree: ``n`` samples (angles, times), ``n_heads`` heads (``H``), ``n_designs`` designs of a
batch (``B``), ``n_orders`` harmonic orders (``M``). ``*batch`` is any leading shape, empty for
a scalar. Inputs also accept plain sequences of floats (lists), as the functions do.
"""

from __future__ import annotations

from collections.abc import Sequence

from jaxtyping import Array, ArrayLike, Complex, Float, Real

ArrayInput = ArrayLike | Sequence[ArrayLike]
"""Any array input without a checked shape: an array, a scalar or a sequence of numbers
(plain or traced, e.g. ``(e_x, 0.0)`` with ``e_x`` under ``jax.grad``)."""
Scalar = Float[ArrayLike, ""] | float
"""One number (a Python float, a 0-d array or a traced scalar), unit as documented."""
Angles = Float[ArrayLike, "*n"] | Sequence[Scalar]
"""Shaft angles (rad) or times (s): a scalar or ``(n,)``."""
HeadAngles = Float[ArrayLike, "n_heads"] | Sequence[Scalar]
"""One value per head, e.g. head azimuths (rad)."""
HeadWeights = Float[ArrayLike, "n_heads"] | Sequence[Scalar] | None
"""Head weights of an average (``None``: equal)."""
HeadErrors = Float[Array, "*n n_heads"]
"""Per-head errors or readings (rad) at each sample (``(n_heads,)`` for a scalar angle)."""
BatchHeadErrors = Float[Array, "n_designs n n_heads"]
"""Per-head errors (rad) of a batch of designs at each sample."""
OrderValues = Float[Array, "n_orders"]
"""One real value per harmonic order ``m = 1 … M``."""
OrderTransfer = Complex[Array, "n_orders"]
"""One complex transfer per harmonic order ``m = 1 … M``."""
SampleValues = Float[ArrayLike, "n"] | Sequence[Scalar]
"""One value per sample (unit of the values)."""
Signals = Float[Array, "n *signals"]
"""Samples of one or more signals: ``(n,)`` or ``(n, k)``."""
Averaged = Float[Array, "*n"]
"""One value per sample (a scalar for one sample)."""
OrderCoefficients = Float[ArrayLike, "*batch n_orders"] | Sequence[Scalar]
"""One real coefficient per harmonic order ``j = 1 … M`` (rad), with any leading batch axes."""
OrderCoefficientsOut = Float[Array, "*batch n_orders"]
"""One real coefficient per harmonic order ``j = 1 … M`` (rad), batch axes of the input."""
HeadReadings = Float[ArrayLike, "n n_heads"]
"""Readings or errors of every head at each sample, rad, ``(n, n_heads)``."""
ScalarOut = Float[Array, ""]
"""One number returned as a 0-d array, unit as documented."""
LayoutPhases = Complex[Array, "n_orders n_heads"]
"""``exp(-i j alpha_k)`` of each order ``j = 1 … M`` (rows) and head ``k`` (columns)."""
BuildNormals = Float[ArrayLike, "n_normals"]
"""One Monte Carlo build's standard-normal deviations ``z`` (dimensionless; layout in
:func:`encdesign.design.deviation_sizes`)."""
BuildValues = Float[Array, "n_builds"]
"""One value per Monte Carlo build (rad, or rad² for a mean square)."""
AngleValues = Float[Array, "n_angles"]
"""One value per evaluation angle of a design (rad)."""
HeadAnglesOut = Float[Array, "n_heads"]
"""One value per head, returned as an array, e.g. head azimuths (rad)."""
FixedEdgeTimes = Float[ArrayLike, "*batch n_fixed n_marks"]
"""Edge times of each fixed sensor by mark index (s)."""
MovingEdgeTimes = Float[ArrayLike, "*batch n_moving n_marks"]
"""Edge times of each moving sensor by mark index (s)."""
FixedValues = Real[ArrayLike, "*batch n_fixed"]
"""One value per fixed sensor (a period in s, or a mark position)."""
MovingValues = Real[ArrayLike, "*batch n_moving"]
"""One value per moving sensor (a mark position)."""
PairOffsets = Float[ArrayLike, "n_fixed n_moving"]
"""One value per fixed × moving sensor pair (rad)."""
PairAngles = Float[Array, "*batch n_fixed n_moving"]
"""One angle per fixed × moving sensor pair (rad), batch axes of the edge times."""
MarkAngles = Float[Array, "n_marks"]
"""One angle per mark of a disk (rad)."""
SampleValuesOut = Float[Array, "n"]
"""One value per sample, returned as an array (unit of the values)."""
