"""The ``encdesign`` command line: :func:`main` and one private module per sub-command."""

from ._main import _load_study as load_study
from ._main import main as main

__all__ = ["load_study", "main"]
