"""Files in and out: recordings of every kind (``encdesign-recording/1``), importers of measured
data with provenance, and the study output plumbing (JSON, PNG). Imports only the base
(``_errors``, ``_progress``): no physics.
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

from . import _closure_recording as _closure_recording  # noqa: F401 (registers kind "closure")
from .._progress import progress_bar as progress_bar
from ._study import (
    float_arg as float_arg,
)
from ._study import (
    int_arg as int_arg,
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
    to_jsonable as to_jsonable,
)
from ._study import (
    write_json as write_json,
)
from ._study import (
    write_results as write_results,
)

# --- checked argument types (the CLI's commands and the studies' flags)
from .._checks import SEED as SEED
from .._checks import SEED_MAX as SEED_MAX

# --- output paths: checked against the inputs before any work, written atomically
from ._paths import (
    OutputGuard as OutputGuard,
    atomic_write_bytes as atomic_write_bytes,
    atomic_write_text as atomic_write_text,
    check_output_folder as check_output_folder,
    check_outputs as check_outputs,
    recording_input_files as recording_input_files,
    recording_output_files as recording_output_files,
)
from ._recording import check_runs_contiguous as check_runs_contiguous

# --- importers of public measured data (``encdesign import``)
from ._realdata import (
    REALDATA_JOBS as REALDATA_JOBS,
    import_magalpha as import_magalpha,
    import_moteus as import_moteus,
    import_nmm as import_nmm,
    import_odrive as import_odrive,
    import_realdata_folder as import_realdata_folder,
    import_servo as import_servo,
    realdata_jobs as realdata_jobs,
)
