"""The errors the library raises: one root, :class:`EncdesignError`.

``except encdesign.EncdesignError`` catches every error encdesign raises on purpose: bad input
(:class:`EncdesignInputError`, also a ``ValueError``), a solver that failed with ``throw=True``
(:class:`OptimisationError`, a ``RuntimeError``), a scale-out
runtime that cannot start (:class:`DistributedError`, ``RuntimeError``) and a diagnosis that
did not complete with ``throw=True`` (:class:`DiagnosisError`, ``RuntimeError``). Each also
derives from the builtin it replaced, so older ``except ValueError`` / ``except
RuntimeError`` code keeps working.
"""

from __future__ import annotations


class EncdesignError(Exception):
    """Root of every error encdesign raises on purpose."""


class EncdesignInputError(EncdesignError, ValueError):
    """Bad user input: a file, field or value that breaks the documented format.

    The message always names the file (when there is one), the field/row/column and what
    was expected. The CLI turns this exception into one line on stderr and exit status 2.
    """


class OptimisationError(EncdesignError, RuntimeError):
    """A driver finished without success and was asked to ``throw``."""


class DistributedError(EncdesignError, RuntimeError):
    """The distributed runtime could not start or lost a process (CLI exit status 1)."""


class DiagnosisError(EncdesignError, RuntimeError):
    """A diagnosis that did not complete (``diagnose(..., throw=True)``)."""


def input_error(where: str, problem: str, expected: str | None = None) -> EncdesignInputError:
    """Build an :class:`EncdesignInputError` with a uniform ``where: problem (expected …)``."""
    msg = f"{where}: {problem}"
    if expected:
        msg += f" (expected {expected})"
    return EncdesignInputError(msg)
