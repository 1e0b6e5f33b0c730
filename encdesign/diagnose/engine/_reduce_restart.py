"""Issue 43 (session 27): a long record's block planned for the base's declared order, and
the restart when the base grows past what the block keeps.

The block of a reduced record (:mod:`._reduce`) is planned for the orders the views scan on
the base of the declared order (twice it, at least ``FinderSettings.scan_order_min``) and
the band of lines (``FinderSettings.reduce_line_hz``), not for every order the base could
grow to: most records' bases do not grow that far, and a longer block is fewer rows for
every later stage. The block keeps every order up to ``orders_kept`` within
``FinderSettings.reduce_attenuation_max`` (:func:`._reduce.orders_kept`). When a growth of
the base (``_engine._grow_to``) proposes an order whose views would scan past
``orders_kept`` (:func:`check_growth`, before the growth's own checks, which scan there;
so also where those checks would have undone the growth), the diagnosis stops
(:class:`GrowthPastBlock`) and starts again from the record, reduced with the block planned
for every order the base can grow to (:func:`._reduce.scan_orders_reached` with growth: the
block before session 27), read again from its file when it was reduced as it was read
(:func:`._reduce_stream.stream_reduce`). The growth is not capped at what the block keeps:
a capped base would leave the orders past it to the candidates, a different diagnosis from
the unreduced record's. So every order and line a view tested is attenuated by at most the
bound, and the restarted diagnosis is the one the block for every growth gives. The
document's ``reduced`` states the plan (``planned_for``, ``orders_needed``,
``orders_kept``) and the restart (``restart``: the order grown to, the scan it needed, the
block left).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from ..._errors import input_error
from ...io._recording import Recording, load_recording
from ._decimate import decimate_recording
from ._document import scan_order_of
from ._protocol import Prepared
from ._reduce import plan as reduce_plan
from ._reduce import reduce_recording
from ._reduce_stream import stream_reduce
from ._settings import FinderSettings
from ._timing import stage

T = TypeVar("T")


class GrowthPastBlock(Exception):
    """The base grew to ``order``: its views would scan to order ``scan``, past the
    ``kept`` orders the reduced record keeps within the bound."""

    def __init__(self, order: int, scan: int, kept: int):
        super().__init__(f"the base grew to order {order}: its views scan to {scan} > {kept}")
        self.order, self.scan, self.kept = int(order), int(scan), int(kept)


def check_growth(prep: Prepared, limit: int, order: int) -> None:
    """Raise :class:`GrowthPastBlock` when the views on a base of ``order`` (within
    ``limit``) would scan past the orders the reduced record keeps (``prep.orders_kept``;
    ``None``: not reduced, or reduced for every order the base can grow to)."""
    kept = prep.orders_kept
    if kept is None:
        return
    scan = scan_order_of(limit, order, prep.settings)
    if scan > kept:
        raise GrowthPastBlock(order, scan, kept)


def orders_checked(reduced: dict) -> int | None:
    """``prep.orders_kept`` of a diagnosis on the record ``reduced`` describes: its
    ``orders_kept`` where it was reduced for the base's declared order and the base grows."""
    ok = reduced.get("applied") and reduced.get("base_grows")
    return reduced.get("orders_kept") if ok and not reduced.get("planned_for_growth") else None


def state_reduction(doc: dict, reduced: dict) -> None:
    """The document says whether the record was reduced to block means (``reduced``:
    :func:`._reduce.plan`); the tests a reduced record cannot make are ``not_testable``."""
    reduced.pop("_source", None)
    doc["reduced"] = reduced
    lost = reduced.get("not_testable") or []
    names = {e["name"] for e in lost}
    doc["not_testable"] = [e for e in doc["not_testable"] if e["name"] not in names] + lost
    if reduced["applied"]:
        dec = reduced.get("decimation") or {}
        by = (
            f", low-passed and decimated by {dec['factor']} to {dec['rate_out_hz']:.4g} Hz"
            if dec.get("applied")
            else ""
        )
        doc["notes"].append(
            f"reduced to the means of blocks of {reduced['block_rows']} rows{by} "
            f"({reduced['rows']} rows to {reduced['reduced_rows']}; attenuation at most "
            f"{reduced['attenuation_max']:g} up to {reduced['f_needed_hz']:.4g} Hz)"
        )
    if "restart" in reduced:
        r = reduced["restart"]
        doc["notes"].append(
            f"the base grew to order {r['grown_to_order']}, whose views scan past the "
            f"{r['orders_kept']} orders blocks of {r['block_rows']} rows keep: diagnosed "
            "again on the block planned for every order the base can grow to"
        )


def _again(
    full: Recording, reduced: dict, order0: int, grows: bool, settings: FinderSettings
) -> tuple[Recording, dict]:
    """The record reduced again with the block planned for every order the base can grow
    to: read again from its file (``reduced["_source"]``) or reduced from ``full``."""
    src = reduced.get("_source")
    if src is not None:
        got = stream_reduce(src, settings, lambda _: (order0, grows), grown=True)
        if got is not None:
            return got
        full = load_recording(src)  # (too short a block for every growth: the whole record)
    info = reduce_plan(full, order0, grows, settings, grown=True)
    return (reduce_recording(full, info) if info["applied"] else full), info


def run_reduced(
    once: Callable[[Recording, dict], T],
    rec: Recording,
    reduced: dict | None,
    order0: int,
    grows: bool,
    settings: FinderSettings,
) -> T:
    """``once(record, reduced)``: the diagnosis of ``rec`` reduced as :func:`._reduce.plan`
    plans it for the base of ``order0`` (``reduced``: already reduced as it was read), and
    again on the block for every order the base can grow to where the base grew past what
    the first block keeps (:class:`GrowthPastBlock`; ``reduced["restart"]`` says so).

    Raises:
        EncdesignInputError: a record given already reduced without its file
            (``reduced["_source"]``) whose base grew past what its block keeps.
    """
    full, given = rec, reduced is not None
    reduced = None if reduced is None else dict(reduced)  # (stage 2 adds to its own copy)
    with stage("reduce"):
        if reduced is None:
            reduced = reduce_plan(rec, order0, grows, settings)
            if reduced["applied"]:
                rec = reduce_recording(rec, reduced)
    rec = _stage2(rec, reduced, settings)
    try:
        return once(rec, reduced)
    except GrowthPastBlock as exc:
        if given and reduced.get("_source") is None:
            raise input_error(
                "reduced",
                f"{exc}; the record was given reduced, without its file to reduce again",
                "the record's file, or a record reduced by open_recording",
            ) from None
        with stage("reduce"):
            del rec
            rec, again = _again(full, reduced, order0, grows, settings)
        again["restart"] = {
            "grown_to_order": exc.order,
            "views_scan_to": exc.scan,
            "orders_kept": exc.kept,
            "block_rows": int(reduced["block_rows"]),
            "reduced_rows": int(reduced["reduced_rows"]),
        }
        rec = _stage2(rec, again, settings)
        return once(rec, again)


def _stage2(rec: Recording, reduced: dict, settings: FinderSettings) -> Recording:
    """The block means ``rec`` (``reduced``: their entry) low-passed and decimated
    (:mod:`._decimate`, stage 2), once; a record not reduced is returned as it is."""
    if not reduced.get("applied") or "decimation" in reduced:
        return rec
    with stage("decimate"):
        return decimate_recording(rec, reduced, settings)
