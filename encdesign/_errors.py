"""Errors raised for bad user input (files, fields, values)."""

from __future__ import annotations


class EncdesignInputError(ValueError):
    """Bad user input: a file, field or value that breaks the documented format.

    The message always names the file (when there is one), the field/row/column and what
    was expected. The CLI turns this exception into one line on stderr and exit status 2.
    """


def input_error(where: str, problem: str, expected: str | None = None) -> EncdesignInputError:
    """Build an :class:`EncdesignInputError` with a uniform ``where: problem (expected …)``."""
    msg = f"{where}: {problem}"
    if expected:
        msg += f" (expected {expected})"
    return EncdesignInputError(msg)
