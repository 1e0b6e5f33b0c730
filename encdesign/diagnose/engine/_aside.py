"""Issue 43 (peak memory per process): whole-record arrays that a stage does not read, set
aside in an unnamed temporary file for the length of that stage and read back bit for bit
after it.

A long record's diagnosis holds a few ``(n, C)`` float64 arrays from one stage to a later
one that the stages between never read: the selection's base and final residuals are
kept for the document and the figures, but the detection bounds, the stage with the
highest peak on a long record, make their own residuals beside them. Each such array is
``8 C`` bytes per reduced row (``C`` channels: at 10^8 rows x 4 heads reduced to blocks
of 12 rows, 8.3 million rows, about 270 MB each). :class:`SetAside` writes them to a
temporary file (``tempfile.TemporaryFile``: deleted when closed, never named) and
:meth:`SetAside.restore` reads them back: the same dtype, shape and bytes, so the
diagnosis is unchanged. The file's pages are the operating system's cache while they
sit there, not the process's memory; writing and reading them back costs two copies of
the arrays (well under a second for 0.5 GB). Where no temporary file can be written
(``OSError``), the arrays stay in memory as before.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence

import numpy as np


class SetAside:
    """``arrays`` written to a temporary file until :meth:`restore` (once); the caller
    drops its own references to them in between, or nothing is freed."""

    def __init__(self, arrays: Sequence[np.ndarray]):
        self._kept: list[np.ndarray] | None = None
        self._meta = [(np.asarray(a).dtype, np.asarray(a).shape) for a in arrays]
        try:
            self._file = tempfile.TemporaryFile(prefix="encdesign-aside-")
            for a in arrays:
                np.ascontiguousarray(a).tofile(self._file)
            self._file.flush()
        except OSError:  # no temporary file: kept in memory (the same arrays)
            self._kept = list(arrays)
            self._file = None

    def restore(self) -> list[np.ndarray]:
        """The arrays, bit for bit (each a fresh array, writable); the file is closed."""
        if self._file is None:
            kept, self._kept = self._kept or [], None
            return kept
        out = []
        try:
            self._file.seek(0)
            for dtype, shape in self._meta:
                count = int(np.prod(shape, dtype=np.int64))
                a = np.fromfile(self._file, dtype=dtype, count=count)
                if a.size != count:
                    raise OSError(f"set-aside file short: {a.size} of {count} values")
                out.append(a.reshape(shape))
        finally:
            self._file.close()
            self._file = None
        return out


__all__ = ["SetAside"]
