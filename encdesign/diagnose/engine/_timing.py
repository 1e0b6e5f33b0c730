"""Wall time per stage of a diagnosis: a light, permanent hook.

:func:`stage` is a context manager. Inside :func:`timing` (the engine opens one per
diagnosis) it charges the wall time spent in its block to the stage's name, *exclusive* of
the stages nested in it: a view scan inside the base fit is charged to ``views``, not to
``base_fit``, so the stages add up to the diagnosis. Outside a diagnosis it costs one
context-variable lookup. The engine reports the sums as the document's ``timings_s`` (wall)
and ``timings_cpu_s`` (CPU) (``docs/diagnose.md``); ``benchmarks/diagnose.py`` records them.
"""

from __future__ import annotations

import contextlib
import contextvars
import time
from collections.abc import Iterator

__all__ = ["StageTimer", "stage", "timing"]


class StageTimer:
    """Exclusive wall time (s) per stage name, in :attr:`totals`; the process's CPU time
    (user + system, all threads) in :attr:`cpu_totals` (on a loaded machine, where the
    wall time is inflated by other processes, the number to compare)."""

    def __init__(self) -> None:
        self.totals: dict[str, float] = {}
        self.cpu_totals: dict[str, float] = {}
        self._stack: list[str] = []
        self._since = time.perf_counter()
        self._cpu_since = time.process_time()

    def _charge(self) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        if self._stack:
            name = self._stack[-1]
            self.totals[name] = self.totals.get(name, 0.0) + (now - self._since)
            self.cpu_totals[name] = self.cpu_totals.get(name, 0.0) + (cpu - self._cpu_since)
        self._since, self._cpu_since = now, cpu

    def enter(self, name: str) -> None:
        """Start charging ``name`` (the enclosing stage pauses)."""
        self._charge()
        self._stack.append(name)

    def leave(self) -> None:
        """Stop charging the innermost stage (the enclosing one resumes)."""
        self._charge()
        self._stack.pop()


_ACTIVE: contextvars.ContextVar[StageTimer | None] = contextvars.ContextVar(
    "encdesign_diagnose_timer", default=None
)


@contextlib.contextmanager
def stage(name: str) -> Iterator[None]:
    """Charge the block's wall time to ``name`` in the active timer (none: nothing)."""
    timer = _ACTIVE.get()
    if timer is None:
        yield
        return
    timer.enter(name)
    try:
        yield
    finally:
        timer.leave()


@contextlib.contextmanager
def timing() -> Iterator[StageTimer]:
    """A fresh :class:`StageTimer`, active for the block (nested diagnoses get their own)."""
    timer = StageTimer()
    token = _ACTIVE.set(timer)
    try:
        yield timer
    finally:
        _ACTIVE.reset(token)
