"""Objective and constraint functions for encoder design: the public face of
:mod:`encdesign.design._objectives` (``from encdesign.objectives import ...`` keeps working).

See that module for the Monte Carlo build pipeline; all values are SI (rad, m). The names are
listed once, in ``design._objectives.__all__``; the objective registry of problem files is
:data:`PROBLEM_OBJECTIVES` (``design._registry``).
"""

from .design._objectives import *  # noqa: F403 (the names of design._objectives.__all__)
from .design._objectives import __all__ as _names
from .design._registry import PROBLEM_OBJECTIVES as PROBLEM_OBJECTIVES

__all__ = [*_names, "PROBLEM_OBJECTIVES"]
