"""The discrepancy finder: fit the model to a recording, locate where they differ, name the
physics left out, and prove it on held-out data; plus the concealed benches it is scored on.
May import physics and io; never design.

``encdesign.diagnose`` (the attribute of the top-level package) is the finder's entry-point
function; this subpackage's contents are imported as ``from encdesign.diagnose import ...``.
"""

from ._conceal import (
    simulate_concealed_bench as simulate_concealed_bench,
    write_concealed as write_concealed,
)
from ._multihead import (
    Diagnosis as Diagnosis,
    EffectResult as EffectResult,
    diagnose as diagnose,
    report_text as diagnosis_report_text,
    write_plots as write_diagnosis_plots,
)
