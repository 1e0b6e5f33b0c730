"""The errors encdesign raises, and :func:`input_error`, which builds the input error's one
uniform message (``where: problem (expected …)``).

The public face of the base module ``encdesign._errors``: the command line and the studies
raise their input errors through these names. The classes are also at the top level
(``encdesign.EncdesignInputError``).
"""

from ._errors import (
    DiagnosisError,
    DistributedError,
    EncdesignError,
    EncdesignInputError,
    OptimisationError,
    input_error,
)

__all__ = [
    "DiagnosisError",
    "DistributedError",
    "EncdesignError",
    "EncdesignInputError",
    "OptimisationError",
    "input_error",
]
