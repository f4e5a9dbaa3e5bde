"""Schmidt "consider" states: states an update may use but must not change.

A consider (Schmidt-Kalman) update keeps some states as they are - a parameter known only
roughly, a quantity the current observation cannot be trusted to move - while their
uncertainty still counts in the innovation covariance and in the other states' gain
(Simon, "Optimal State Estimation", 2006, sec. 7.5; Brown & Hwang, sec. 9.2):

    K = P H^T S^-1 with the rows of the considered states set to zero,
    P' = (I - K H) P (I - K H)^T + K R K^T   (Joseph form: right for any gain, so P stays
                                              consistent with the suboptimal K).

With K's considered rows zero, the Joseph form gives, for the estimated states s and the
considered ones c: P'_ss and P'_sc exactly as the optimal update gives them, and
P'_cc = P_cc, x'_c = x_c. So a consider update *is* the filter's ordinary joint update
followed by restoring x_c and P_cc (:func:`restore_considered`): one implementation for
every backend, no kernel of its own. (Row-by-row sequential updates would differ, since
each row's S would see the reduced P_cc: consider updates are always joint.)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["consider_indices", "restore_considered"]


def consider_indices(consider: Sequence[int] | Sequence[bool] | np.ndarray, n: int) -> np.ndarray:
    """The indices (sorted, unique) of the considered states of an n-state filter, from a
    boolean mask of length n or a sequence of indices; ValueError naming what is wrong."""
    a = np.asarray(consider)
    if a.dtype == bool:
        if a.shape != (n,):
            raise ValueError(f"consider mask has shape {a.shape}, expected ({n},)")
        return np.flatnonzero(a)
    if a.size == 0:
        return np.zeros(0, dtype=np.intp)
    if a.ndim != 1 or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"consider must be a boolean mask or state indices, got {consider!r}")
    if a.min() < 0 or a.max() >= n:
        raise ValueError(f"consider index out of range for {n} states: {a.tolist()}")
    return np.unique(a)


def restore_considered(
    x_prior: np.ndarray,
    P_prior: np.ndarray,
    x_post: np.ndarray,
    P_post: np.ndarray,
    idx: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(x, P) of the Schmidt update from the optimal joint update's (``x_post``, ``P_post``):
    the considered states ``idx`` keep their prior value and their prior covariance block
    (see the module docstring). New arrays; the inputs are not modified."""
    x = x_post.copy()
    P = P_post.copy()
    x[idx] = x_prior[idx]
    P[np.ix_(idx, idx)] = P_prior[np.ix_(idx, idx)]
    return x, P
