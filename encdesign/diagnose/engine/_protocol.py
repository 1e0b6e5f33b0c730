"""What a kind hands the engine (:class:`KindData`) and the prepared record (:class:`Prepared`,
its row columns); the kind itself is :class:`~encdesign.diagnose.engine._kind.AbstractKind`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, MutableMapping
from typing import Any

import numpy as np

from ._candidates import Context
from ._settings import DEFAULT_SETTINGS, FinderSettings
from ._views_sums import ViewSums

# ----------------------------------------------------------------------------- kind data


@dataclasses.dataclass
class KindData:
    """What a kind hands the engine (numpy, SI). Built by the kind's ``data(rec)``.

    Attributes:
        y: observations ``(n, C)`` whose model is the sum of the terms (e.g. reading -
            theta_ref), in ``unit``.
        shaft: shaft angle per row (rad), used to find non-steady motion and revolutions.
        t: time within the run, s. run: run id per row (any ints).
        reading: each channel's reading ``(n, C)`` (rad) for line-phase terms; ``None``:
            read per chunk from ``reading_cols`` (the recording's own columns, one per
            channel: no copy per row).
        theta_ref: reference angle or ``None``. temp: ``temp_c`` or ``None``.
        alpha: channel azimuths (rad). radius_m: optical radius or ``None``.
        signal_periods: signal periods per revolution (0: unknown).
        project: remove the per-sample channel mean (no reference angle: only channel
            differences are observable).
        unit: unit of ``y``. channel_names: e.g. ``h0``...
        sensor: ``[encoder] sensor``.
        where: file name for messages.
        drive: ``True``: the shaft is a commanded drive with a large ripple of its own
            (``motion``, ``quadrature``): rows are steady within
            ``FinderSettings.steady_tolerance_drive``, else ``steady_tolerance``.
        speed_window: the speed is measured over this fraction of the run (at least 5 rows;
            longer for a motor whose own ripple is large).
        segments: optional steady-segment id per row (>= 0), given by the kind instead of
            being found from the shaft motion (e.g. a quadrature capture sorted by phase
            has no motion to segment); ``None``: found by :func:`find_motion_segments`.
        masked: optional ``(mask (n,) bool, reason)`` pairs: rows the kind knows to leave out
            of every fit (e.g. clipped signals); each is reported as one excluded segment
            (first to last masked row) with its reason and the number of stretches.
        reading_cols: the recording's own reading columns, one per channel, when
            ``reading`` is ``None``.
        constants: the kind's own recording constants (arrays) its terms read as
            ``x[name]``, beside the engine's (:data:`~._candidates.CONSTANTS`); built once
            here, read-only.
    """

    y: np.ndarray
    shaft: np.ndarray
    t: np.ndarray
    run: np.ndarray
    reading: np.ndarray | None
    theta_ref: np.ndarray | None
    temp: np.ndarray | None
    alpha: np.ndarray
    radius_m: float | None
    signal_periods: int
    project: bool
    unit: str
    channel_names: list[str]
    sensor: str
    where: str
    drive: bool = False
    speed_window: float = 0.01
    segments: np.ndarray | None = None
    masked: tuple[tuple[np.ndarray, str], ...] = ()
    reading_cols: tuple[np.ndarray, ...] = ()
    constants: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if self.reading is None and len(self.reading_cols) != self.y.shape[1]:
            raise ValueError("KindData: reading is None and reading_cols is not one per channel")


def drive_channel(
    y: np.ndarray,
    shaft: np.ndarray,
    t: np.ndarray,
    run: np.ndarray,
    *,
    unit: str,
    channel_name: str,
    sensor: str,
    where: str,
    signal_periods: int = 0,
) -> dict:
    """The :class:`KindData` fields of a one-channel record of a commanded drive
    (``motion``, ``quadrature``): ``y`` ``(n, 1)`` in ``unit``, read against the shaft angle
    ``shaft`` (rad) itself, no reference, temperature or head geometry; ``drive=True`` and a
    5 % speed window (the motor's own ripple is large). A kind passes them on with its own
    extra fields: ``QuadratureData(**drive_channel(...), start=...)``."""
    return dict(
        y=y,
        shaft=shaft,
        t=t,
        run=run,
        reading=shaft[:, None],
        theta_ref=None,
        temp=None,
        alpha=np.zeros(1),
        radius_m=None,
        signal_periods=signal_periods,
        project=False,
        unit=unit,
        channel_names=[channel_name],
        sensor=sensor,
        where=where,
        drive=True,
        speed_window=0.05,
    )


@dataclasses.dataclass(frozen=True)
class NoiseEstimate:
    """What a kind's ``noise`` hook found on the base residual.

    Attributes:
        sigma: noise std per channel ``(C,)``, unit of ``y``.
        info: the kind's own findings of its noise stage (a type of the kind's; e.g. the
            sds levels and common-order powers), handed back read-only to its candidates and
            summary as ``Context.noise_info``; ``None``: none.
    """

    sigma: np.ndarray
    info: Any = None


# ----------------------------------------------------------------------------- prepared


class RowColumns(MutableMapping):
    """Row columns of a prepared record.

    Stored columns are arrays (often the recording's own, not copies). ``run_onehot`` (n, R)
    is made on access from the run index; *lazy* columns are functions ``fn(lo, hi)`` of a row
    range, computed on access (whole column) or per chunk by :meth:`column`, so that a
    column that follows from others (time across runs, the segment speed, a signal phase)
    costs no memory per row. Assigning an array stores it; :meth:`set_lazy` assigns a
    function."""

    def __init__(
        self,
        cols: dict[str, np.ndarray],
        run: np.ndarray,
        n_runs: int,
        lazy: dict[str, Callable[[int, int | None], np.ndarray]] | None = None,
    ):
        self._d = dict(cols)
        self._lazy = dict(lazy or {})
        self.run = run
        self.n_runs = n_runs

    def onehot(self, lo: int = 0, hi: int | None = None) -> np.ndarray:
        """One-hot run membership of rows ``lo:hi``."""
        r = self.run[lo:hi]
        out = np.zeros((r.size, self.n_runs))
        out[np.arange(r.size), r] = 1.0
        return out

    def column(self, k: str, lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Rows ``lo:hi`` of column ``k`` (a lazy column computes only those rows)."""
        if k in self._d:
            return self._d[k][lo:hi]
        if k in self._lazy:
            return self._lazy[k](lo, hi)
        if k == "run_onehot":
            return self.onehot(lo, hi)
        raise KeyError(k)

    def take(self, k: str, idx) -> np.ndarray:
        """Column ``k`` at row indices ``idx`` (an int or an array): a lazy column is
        computed over the span of those rows only."""
        idx = np.asarray(idx)
        if idx.size == 0:
            return self.column(k, 0, 0)
        lo, hi = int(idx.min()), int(idx.max()) + 1
        return self.column(k, lo, hi)[idx - lo]

    def set_lazy(self, k: str, fn: Callable[[int, int | None], np.ndarray]) -> None:
        """Make ``k`` a lazy column ``fn(lo, hi)``."""
        self._d.pop(k, None)
        self._lazy[k] = fn

    def __getitem__(self, k: str) -> np.ndarray:
        return self.column(k)

    def __setitem__(self, k: str, v: np.ndarray) -> None:
        self._lazy.pop(k, None)
        self._d[k] = v

    def __delitem__(self, k: str) -> None:
        if k in self._d:
            del self._d[k]
        else:
            del self._lazy[k]

    def __contains__(self, k: object) -> bool:
        return k in self._d or k in self._lazy or k == "run_onehot"

    def __iter__(self):
        yield from self._d
        yield from (k for k in self._lazy if k not in self._d)
        if "run_onehot" not in self._d and "run_onehot" not in self._lazy:
            yield "run_onehot"

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def stored(self):
        """The stored columns (without the derived one-hot and the lazy columns)."""
        return self._d.items()

    def snapshot(self) -> tuple[dict, dict]:
        """The columns as they are now (references, no copies), for :meth:`restore`."""
        return dict(self._d), dict(self._lazy)

    def restore(self, state: tuple[dict, dict]) -> None:
        """Back to a :meth:`snapshot` (e.g. a refinement found to diverge)."""
        self._d, self._lazy = dict(state[0]), dict(state[1])

    def names(self) -> list[str]:
        """Every column a term can read, ``run_onehot`` last."""
        return [k for k in self if k != "run_onehot"] + ["run_onehot"]


class KeptRows(MutableMapping):
    """The row columns over the kept samples, selected on access (no stored copy; the
    columns themselves when every row is kept). Assigned columns are stored as given."""

    def __init__(self, rows: RowColumns, keep: np.ndarray):
        self._rows = rows
        self._keep = keep
        self._all = bool(keep.all())
        self._own: dict[str, np.ndarray] = {}

    def __getitem__(self, k: str) -> np.ndarray:
        if k in self._own:
            return self._own[k]
        v = self._rows[k]
        return v if self._all else v[self._keep]

    def __setitem__(self, k: str, v: np.ndarray) -> None:
        self._own[k] = v

    def __delitem__(self, k: str) -> None:
        del self._own[k]

    def __iter__(self):
        yield from self._rows
        yield from (k for k in self._own if k not in self._rows)

    def __len__(self) -> int:
        return len(set(self._rows) | set(self._own))


@dataclasses.dataclass
class Prepared:
    """A recording ready to fit: kept rows, row columns, noise, folds, nuisances."""

    kd: KindData
    ctx: Context
    y: np.ndarray  # (n, C), rows sorted run-by-run in file order
    rows: RowColumns  # row columns for the terms
    consts: Mapping[str, Any]  # the terms' recording constants, built once (read-only)
    keep: np.ndarray  # bool (n,)
    fold: np.ndarray  # int (n,), -1 for excluded rows
    seg: np.ndarray  # int (n,) steady segment id, -1 excluded
    sigma: np.ndarray  # (C,) noise std per channel
    excluded: list[dict]
    glitches: list[dict]
    count_jumps: list[dict]
    gaps: list[dict]
    fold_design: dict
    run_ids: np.ndarray
    run: np.ndarray  # run index 0..R-1
    settings: FinderSettings = DEFAULT_SETTINGS  # the thresholds of this diagnosis
    # steps of a channel's error function of the angle (recurring count jumps), in the base
    angle_steps: list[dict] = dataclasses.field(default_factory=list)
    # the base model's Jacobian on every row (n, C, p), projected like the data, not whitened;
    # set after the base fit on a record small enough (``_views_modulated.base_jacobian``)
    base_jacobian: np.ndarray | None = None
    # the base model's terms as the base fit left them (the views that project the base's own
    # columns out read them: ``kinds/multihead/_order_step_bins``)
    base_terms: tuple | None = None
    # the widest shaft-angle span (rad) of a run's kept rows where every run covers less than
    # one turn, else None (``_prepare.part_turn_span``; computed once where the record is
    # prepared)
    part_turn_span: float | None = None
    # the effective degrees of freedom of each channel's noise estimate ``sigma`` (C,) where it
    # is estimated from the residual's periodogram (``_noise.noise_spectral_dof``), else None
    # (the views then treat ``sigma`` as known); the spectrum view's test reads it
    # (``_views_estimated.estimated_test``)
    noise_dof: np.ndarray | None = None
    # issue 43: the highest order a record reduced for the base's declared order keeps within
    # the bound, where the base grows (``_reduce_restart.check_growth``: a growth whose views
    # would scan past it restarts the diagnosis), else None
    orders_kept: int | None = None
    # the sums the views keep across this record's scans (``_views_sums``): owned by this
    # diagnosis alone, never shared with another record's
    view_sums: ViewSums = dataclasses.field(default_factory=ViewSums, compare=False, repr=False)

    @property
    def n(self) -> int:
        """Rows."""
        return self.y.shape[0]

    @property
    def n_channels(self) -> int:
        """Channels."""
        return self.y.shape[1]

    @property
    def n_values(self) -> float:
        """Independent fitted values (kept rows x channels, less the projection)."""
        C = self.n_channels
        return float(self.keep.sum() * (C - 1 if self.kd.project else C))


def steady_tolerance(kd: KindData, settings) -> float:
    """The relative speed deviation beyond which a row of ``kd`` is not steady (the
    ``FinderSettings`` field of its kind: ``steady_tolerance_drive`` for a drive)."""
    return settings.steady_tolerance_drive if kd.drive else settings.steady_tolerance


class FitDivergence(ArithmeticError):
    """A stage of the fit would diverge (issue 44 A): raised by a kind's hook (e.g. the
    shaft-angle refinement) with the cause in its message; the engine reports it under
    ``base.fit_failures`` and goes on from the last sound fit, so it never reaches the
    verdict."""


@dataclasses.dataclass(frozen=True)
class KindView:
    """A kind's own view, ``fn(prep, rw, scan_order) -> [Finding, ...]`` on the whitened
    residual as an array, with the ``view`` names of the findings it reports (the detection
    bounds run only the views a candidate's signature names).

    ``rows``: the view reads ``rw`` only by rows (``rw[i]``, ``rw[a:b]``, ``rw[idx]``,
    ``rw[idx, ch]``) and its ``shape``: it is handed the engine's
    :class:`~._views_sums.Whitened` residual, whitened where it is indexed (the same numbers),
    instead of a whitened copy of the whole residual (``8 C`` bytes per row at every scan:
    issue 43, peak memory)."""

    fn: Any
    names: tuple[str, ...]
    rows: bool = False

    def __call__(self, prep, rw: np.ndarray, scan_order: int) -> list:
        return self.fn(prep, rw, scan_order)
