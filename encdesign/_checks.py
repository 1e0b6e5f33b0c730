"""Checked number types for argument parsers (the CLI's commands and the studies' flags).

:func:`int_arg` and :func:`float_arg` are argparse ``type`` callables that refuse a value
outside its documented range, a non-finite number and Python literals such as ``1_0``
(only plain decimal digits, an optional sign and, for numbers, a decimal point and exponent
are read) while the arguments are parsed, so the message names the flag and no work starts.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable

__all__ = ["SEED", "SEED_MAX", "float_arg", "int_arg"]

_INT = re.compile(r"[+-]?[0-9]+")
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:inf|nan)", re.I)


SEED_MAX = 2**63 - 1
"""Largest PRNG seed (JAX keys take a 64-bit integer)."""


def int_arg(lower: int | None = None, upper: int | None = None) -> Callable[[str], int]:
    """An argparse ``type`` for an integer in ``[lower, upper]``."""

    def parse(text: str) -> int:
        try:
            if not _INT.fullmatch(text.strip()):
                raise ValueError(text)
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if lower is not None and v < lower:
            raise argparse.ArgumentTypeError(f"{v} is below {lower} ({_range(lower, upper)})")
        if upper is not None and v > upper:
            raise argparse.ArgumentTypeError(f"{v} is above {upper} ({_range(lower, upper)})")
        return v

    parse.__name__ = "integer"
    vars(parse)["bounds"] = (lower, upper)  # the range, for tests and documentation
    return parse


def float_arg(
    lower: float | None = None,
    upper: float | None = None,
    *,
    lower_open: bool = False,
) -> Callable[[str], float]:
    """An argparse ``type`` for a finite number in ``[lower, upper]`` (``(lower, …`` with
    ``lower_open``)."""

    def parse(text: str) -> float:
        try:
            if not _FLOAT.fullmatch(text.strip()):
                raise ValueError(text)
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text!r} is not finite")
        rng = _range(lower, upper, lower_open)
        if lower is not None and (v < lower or (lower_open and v == lower)):
            raise argparse.ArgumentTypeError(f"{text} is out of range ({rng})")
        if upper is not None and v > upper:
            raise argparse.ArgumentTypeError(f"{text} is out of range ({rng})")
        return v

    parse.__name__ = "number"
    vars(parse)["bounds"] = (lower, upper)  # the range, for tests and documentation
    return parse


def _range(lower, upper, lower_open: bool = False) -> str:
    def fmt(v):
        return str(v) if isinstance(v, int) else f"{v:g}"

    lo = "" if lower is None else f"{fmt(lower)} {'<' if lower_open else '<='} "
    hi = "" if upper is None else f" <= {fmt(upper)}"
    return f"expected {lo}value{hi}"


SEED = int_arg(0, SEED_MAX)
"""argparse ``type`` of a PRNG seed: an integer ``0 … 2^63-1``."""
