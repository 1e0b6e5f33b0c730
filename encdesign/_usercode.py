"""Running the user's own code (objective modules, ``--candidates`` files) under a guard.

User code may end the process (``sys.exit``), raise ``KeyboardInterrupt`` or any exception,
at import or when its function is called during a run. :func:`user_code` turns each of these
into an :class:`~encdesign.EncdesignInputError` naming the module and function, so the CLI
exits 2 with one line (never 0 without its outputs, never a traceback).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, ParamSpec, TypeVar

from ._errors import EncdesignInputError, input_error

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

P = ParamSpec("P")
R = TypeVar("R")
Item = TypeVar("Item", bound="DataclassInstance")

__all__ = ["guarded", "user_code", "user_module_items"]


@contextlib.contextmanager
def user_code(where: str, *, keep: tuple[type[BaseException], ...] = ()) -> Iterator[None]:
    """Run the block as user code named ``where`` (e.g. ``"objective 'pkg.mod:fn'"``).

    Args:
        where: names the module and function for the message.
        keep: exception types let through unchanged (besides the project's input error),
            for callers that report those themselves in the user's terms.

    Raises:
        EncdesignInputError: the user code called ``sys.exit``, was interrupted, or raised.
    """
    try:
        yield
    except SystemExit as exc:
        raise input_error(
            where, f"called sys.exit({exc.code!r})", "user code that returns, not exits"
        ) from None
    except KeyboardInterrupt:
        raise input_error(where, "raised KeyboardInterrupt", "user code that returns") from None
    except Exception as exc:
        if isinstance(exc, (EncdesignInputError, *keep)):
            raise
        raise input_error(where, f"raised {type(exc).__name__}: {exc}") from exc


def guarded(
    where: str, fn: Callable[P, R], *, keep: tuple[type[BaseException], ...] = ()
) -> Callable[P, R]:
    """``fn`` wrapped so that every call runs under :func:`user_code` (``where`` names it)."""

    @functools.wraps(fn)
    def call(*args: P.args, **kwargs: P.kwargs) -> R:
        with user_code(where, keep=keep):
            return fn(*args, **kwargs)

    return call


def user_module_items(
    where: str,
    load: Callable[[], object],
    attr: str,
    item_type: type[Item],
    callables: tuple[str, ...] = (),
) -> tuple[Item, ...]:
    """The sequence ``attr`` of a user module, its items' user functions guarded.

    Args:
        where: names the file (``"--candidates my.py"``).
        load: imports the module and returns it (run under :func:`user_code`).
        attr: the module attribute holding the items (``"CANDIDATES"``).
        item_type: the type every item must have (a dataclass).
        callables: the items' fields holding user functions: each is wrapped so that a
            call during the run is guarded too (named ``where: ITEM.FIELD``).

    Raises:
        EncdesignInputError: the import failed or exited, or ``attr`` is missing, not a
            list or tuple, or holds an item of another type.
    """
    with user_code(f"{where} (at import)"):
        mod = load()
    items = getattr(mod, attr, None)
    expected = f"{attr} = [{item_type.__name__}(...), ...]"
    if items is None:
        raise input_error(where, f"defines no {attr}", expected)
    if not isinstance(items, list | tuple):
        raise input_error(where, f"{attr} is a {type(items).__name__}, not a list", expected)
    for i, c in enumerate(items):
        if not isinstance(c, item_type):
            raise input_error(where, f"{attr}[{i}] is a {type(c).__name__}", expected)
    out: list[Item] = []
    for c in items:
        name = getattr(c, "name", type(c).__name__)
        repl = {
            f: guarded(f"{where}: {name}.{f}", getattr(c, f))
            for f in callables
            if callable(getattr(c, f, None))
        }
        out.append(dataclasses.replace(c, **repl) if repl else c)
    return tuple(out)
