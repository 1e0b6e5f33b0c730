"""How a trial fit's candidate term stands against the base model's columns (stage 4,
:mod:`._select`): its largest canonical correlation with them, and the columns to hold at
zero so that the rest of it can still be tested."""

from __future__ import annotations

import math

import numpy as np

from ._fit import FitResult, Term


def collinearity(fit: FitResult, n_base_terms: int) -> float:
    """Largest canonical correlation between the last term's columns and the base's."""
    s0, s1 = fit.slices[-1]
    base_n = fit.slices[n_base_terms - 1][1] if n_base_terms else 0
    A = fit.A
    p = A.shape[0]
    if s1 <= s0 or base_n == 0:
        return 0.0
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    b = np.arange(base_n)
    e = np.arange(s0, s1)
    Abb, Aee, Abe = An[np.ix_(b, b)], An[np.ix_(e, e)], An[np.ix_(b, e)]
    try:
        Lb = np.linalg.pinv(Abb, rcond=1e-10, hermitian=True)
        Le = np.linalg.pinv(Aee, rcond=1e-10, hermitian=True)
    except np.linalg.LinAlgError:
        return float("nan")
    M = Le @ Abe.T @ Lb @ Abe
    ev = np.linalg.eigvals(M).real
    del p
    return float(math.sqrt(min(max(ev.max(initial=0.0), 0.0), 1.0)))


def collinear_columns(fit: FitResult, n_base_terms: int, refuse: float) -> np.ndarray:
    """Local indices (in the last term's free vector) to hold so that the rest of the term
    has a canonical correlation with the base model's columns of at most
    ``settings.collinear_refuse``: greedily, the column best explained by the base and the columns
    kept so far first."""
    s0, s1 = fit.slices[-1]
    base_n = fit.slices[n_base_terms - 1][1] if n_base_terms else 0
    if s1 <= s0 or base_n == 0:
        return np.zeros(0, int)
    A = fit.A
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    b = np.arange(base_n)
    Lb = np.linalg.pinv(An[np.ix_(b, b)], rcond=1e-10, hermitian=True)
    keep = list(range(s0, s1))
    held: list[int] = []
    for _ in range(s1 - s0):
        e = np.asarray(keep)
        Aee, Abe = An[np.ix_(e, e)], An[np.ix_(b, e)]
        Le = np.linalg.pinv(Aee, rcond=1e-10, hermitian=True)
        ev = np.linalg.eigvals(Le @ Abe.T @ Lb @ Abe).real
        if ev.size == 0 or ev.max() <= refuse**2:
            break
        r2 = np.einsum("bj,bc,cj->j", Abe, Lb, Abe)
        j = int(np.argmax(r2))
        held.append(keep.pop(j) - s0)
        if not keep:
            break
    return np.asarray(sorted(held), int)


def hold(term: Term, local: np.ndarray) -> Term:
    """``term`` with the free scalars at ``local`` (free-vector indices) held at zero."""
    t2 = term.copy()
    pos = 0
    local = set(int(i) for i in local)
    for q in t2.cand.params:
        m = t2.free[q.name]
        flat = m.ravel()
        v = t2.values[q.name].ravel()
        for j in np.flatnonzero(flat):
            if pos in local:
                flat[j] = False
                v[j] = 0.0
            pos += 1
        t2.free[q.name] = flat.reshape(m.shape)
        t2.values[q.name] = v.reshape(m.shape)
    return t2


def local_names(held_term: Term, local: np.ndarray, fitted: Term) -> list[str]:
    del fitted
    names = []
    for q in held_term.cand.params:
        m = held_term.free[q.name]
        for ij in np.argwhere(~m):
            names.append(f"{q.name}{[int(v) for v in ij] if ij.size else ''}")
    del local
    return names


__all__ = ["collinear_columns", "collinearity", "hold", "local_names"]
