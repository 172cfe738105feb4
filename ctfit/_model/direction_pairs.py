"""A measurement's distinct direction pairs and each sample's pair, in NumPy alone (no JAX): what
:meth:`~ctfit.Measurement.directions` returns, computed where a reader has the angles (a helper
process parsing a large CSV computes it while the command starts JAX: :mod:`~ctfit._io.read_ahead`)."""

from __future__ import annotations

import numpy as np

__all__ = ["unique_direction_pairs"]


def _new_rows(a: np.ndarray) -> np.ndarray:
    """Whether each row of ``a`` differs from the one before (the first row: True)."""
    new = np.empty(len(a), dtype=bool)
    new[0] = True
    np.any(a[1:] != a[:-1], axis=1, out=new[1:])
    return new


def unique_direction_pairs(theta_i: np.ndarray, phi_i: np.ndarray, theta_o: np.ndarray, phi_o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows (θ_i, φ_i, θ_o, φ_o), shape (D, 4), in lexicographic order, and each
    sample's row index (N,), both read-only: ``np.unique(axis=0, return_inverse=True)``'s result,
    ~10× faster on large files (a lexsort of the four columns, or one sort where no two rows share
    θ_i, as in scattered data; rows that repeat the row before — the bands of one direction pair,
    as files usually list them — are sorted once).

    >>> pairs, index = unique_direction_pairs(*np.array([[30.0, 0, 30, 180], [30, 0, 30, 180], [10, 0, 10, 180]]).T)
    >>> pairs.tolist(), index.tolist()
    ([[10.0, 0.0, 10.0, 180.0], [30.0, 0.0, 30.0, 180.0]], [1, 1, 0])
    """
    a = np.stack([theta_i, phi_i, theta_o, phi_o], axis=1)
    if len(a) == 0:
        a.setflags(write=False)
        return a, np.zeros(0, dtype=np.intp)
    run_start = _new_rows(a)  # runs of equal consecutive rows
    run = np.cumsum(run_start) - 1
    heads = a[run_start]
    order = np.argsort(heads[:, 0], kind="stable")
    if np.any(heads[order[1:], 0] == heads[order[:-1], 0]):  # ties in θ_i (a grid): the whole lexsort
        order = np.lexsort(heads.T[::-1])
    s = heads[order]
    new = _new_rows(s)
    head_index = np.empty(len(heads), dtype=np.intp)
    head_index[order] = np.cumsum(new) - 1
    index = head_index[run]
    pairs = s[new]
    pairs.setflags(write=False)
    index.setflags(write=False)
    return pairs, index
