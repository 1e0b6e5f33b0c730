"""The discrepancy finder: fit the model to a recording, locate where they differ, name the
physics left out, and prove it on held-out data; plus the concealed benches it is scored on.
May import physics and io; never design.

``encdesign.diagnose`` (the attribute of the top-level package) is the finder's entry-point
function; this subpackage's contents are imported as ``from encdesign.diagnose import ...``.
"""

from pathlib import Path

from .engine._candidates import (
    Candidate as Candidate,
    Context as Context,
    Param as Param,
    Probe as Probe,
)
from ._dispatch import (
    Diagnosis as Diagnosis,
    diagnose as diagnose,
    load_candidates as load_candidates,
)
from ._dispatch import (
    open_recording as open_recording,
)
from .engine._discover_export import (
    discovered_candidate as discovered_candidate,
)
from .engine._discover_export import (
    export_candidates as export_candidates,
)
from .kinds.motion._motion import candidate_orders as candidate_orders
from .engine._results import (
    Alternative as Alternative,
    BaseOrder as BaseOrder,
    Confounded as Confounded,
    DetectionBound as DetectionBound,
    Effect as Effect,
    Finding as Finding,
    OrderTrial as OrderTrial,
    PlotData as PlotData,
    Refusal as Refusal,
)
from .engine._plots import engine_plots as write_diagnosis_plots
from .engine._html import (
    render_html as render_diagnosis_html,
    write_html as write_diagnosis_html,
)
from .engine._settings import (
    DEFAULT_SETTINGS as DEFAULT_SETTINGS,
    FinderSettings as FinderSettings,
)
from .engine._settings_table import settings_table as settings_table
from .kinds.sds._sds_readout import (
    SDSRecordingResult as SDSRecordingResult,
)
from .kinds.sds._sds_readout import (
    sds_readings_from_recording as sds_readings_from_recording,
)


def diagnosis_report_text(d: Diagnosis) -> str:
    """The plain-text report of a diagnosis."""
    return d.doc.get("report", "")


SCHEMA_PATH = Path(__file__).with_name("diagnosis.schema.json")
"""The JSON Schema every diagnosis document follows."""
