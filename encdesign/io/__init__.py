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
