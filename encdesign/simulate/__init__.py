"""Bench simulators: every generator of bench data in one place (``docs/DEVELOPING.md``).

* multihead benches of a design file (:func:`simulate_bench`, :func:`simulate_recording`);
* the one ``sds`` simulator (:func:`sds_bench_columns`, :func:`simulate_sds_recording`);
* dual-closure tests (:func:`simulate_closure_readings`) and stepped-sine shaker tests
  (:func:`simulate_shaker_steps`);
* the finder's concealed benches: multihead (:func:`simulate_concealed_bench`,
  :func:`write_concealed`), a sensor against a reference (:func:`simulate_sensor_reference`,
  :func:`write_sensor_reference`), ``sds`` (:func:`write_concealed_sds`) and the blind
  benchmark's plans of every kind (multihead, sensor, motion, quadrature: :func:`draw_plan`,
  :func:`simulate_plan`).

A tool layer above ``design``, ``diagnose`` and ``calibrate``: it may import physics, io and
those tools' types (a :class:`~encdesign.design.Design`, ``ShakerSteps``), and none of them
imports it; the effects it conceals are written from ``physics`` (``_effects``,
``_sensor_effects``), never with the finder's own terms. ``cli`` and ``studies`` use both the
simulators and the finder.
"""

from ._closure import simulate_closure_readings as simulate_closure_readings
from ._conceal import (
    CONCEALMENTS as CONCEALMENTS,
)
from ._conceal import (
    HIDDEN as HIDDEN,
)
from ._conceal import (
    LAYOUTS as LAYOUTS,
)
from ._conceal import (
    simulate_concealed_bench as simulate_concealed_bench,
)
from ._conceal import (
    write_concealed as write_concealed,
)
from ._conceal_bench import (
    MOTION_EFFECTS as MOTION_EFFECTS,
)
from ._conceal_bench import (
    MULTIHEAD_EFFECTS as MULTIHEAD_EFFECTS,
)
from ._conceal_bench import (
    QUADRATURE_EFFECTS as QUADRATURE_EFFECTS,
)
from ._conceal_bench import (
    SENSOR_EFFECTS as SENSOR_EFFECTS,
)
from ._conceal_bench import (
    draw_plan as draw_plan,
)
from ._conceal_bench import (
    fix_plan as fix_plan,
)
from ._conceal_bench import (
    simulate_plan as simulate_plan,
)
from ._conceal_bench import (
    simulate_quadrature as simulate_quadrature,
)
from ._conceal_reference import (
    effect_rms_params as effect_rms_params,
)
from ._conceal_reference import (
    random_reference_bench as random_reference_bench,
)
from ._conceal_reference import (
    simulate_sensor_reference as simulate_sensor_reference,
)
from ._conceal_reference import (
    write_sensor_reference as write_sensor_reference,
)
from ._conceal_sds import (
    SDS_CATALOG as SDS_CATALOG,
)
from ._conceal_sds import (
    SDS_HIDDEN as SDS_HIDDEN,
)
from ._conceal_sds import (
    sds_bench_design as sds_bench_design,
)
from ._conceal_sds import (
    write_concealed_sds as write_concealed_sds,
)
from ._multihead import (
    simulate_bench as simulate_bench,
)
from ._multihead import (
    simulate_recording as simulate_recording,
)
from ._sds import (
    RUN_SPACING_REVS as RUN_SPACING_REVS,
)
from ._sds import (
    sds_bench_columns as sds_bench_columns,
)
from ._sds import (
    simulate_sds_recording as simulate_sds_recording,
)
from ._shaker import simulate_shaker_steps as simulate_shaker_steps
