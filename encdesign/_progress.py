"""Progress bars for long work, through ``tqdm``: rate, ETA, and quiet off a terminal."""

from __future__ import annotations

import sys
from typing import IO, TYPE_CHECKING

if TYPE_CHECKING:  # imported where a bar is made (issue 43: a quiet diagnosis never does)
    from tqdm.auto import tqdm


def progress_bar(
    label: str, total: int, enabled: bool = True, *, unit: str = "it", stream: IO[str] | None = None
) -> tqdm:
    """A ``tqdm`` bar on stderr for ``total`` items labelled ``label``.

    Args:
        label: what is being counted (shown left of the bar).
        total: number of items.
        enabled: ``False`` silences it; ``True`` shows it when the stream is a terminal
            (tqdm's ``disable=None``: quiet in pipes, logs and CI).
        unit: the item's name in the rate (``"build"``, ``"case"``, ...).
        stream: where to draw (default ``sys.stderr``).

    Use as a context manager; ``update(n)`` advances by ``n`` items.
    """
    from tqdm.auto import tqdm

    return tqdm(
        total=int(total),
        desc=label,
        unit=unit,
        file=stream if stream is not None else sys.stderr,
        disable=None if enabled else True,
        dynamic_ncols=True,
        leave=True,
    )
