"""Files in and out: recordings of every kind (``encdesign-recording/1``), importers of measured
data with provenance, and the study output plumbing (JSON, PNG). May import physics.
"""

from ._recording import (
    Recording as Recording,
)
from ._recording import (
    load_recording as load_recording,
)
from ._recording import (
    write_recording as write_recording,
)
from ._sds_recording import (
    SDSRecordingResult as SDSRecordingResult,
)
from ._sds_recording import (
    sds_readings_from_recording as sds_readings_from_recording,
)
from ._sds_recording import (
    simulate_sds_recording as simulate_sds_recording,
)

from ._study import (
    new_figure as new_figure,
)
from ._study import (
    save_figure as save_figure,
)
from ._study import (
    study_parser as study_parser,
)
from ._study import (
    write_results as write_results,
)

from . import _closure_recording as _closure_recording  # noqa: F401 (registers kind "closure")
