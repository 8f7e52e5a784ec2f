"""The assignment of least total cost, which matches detected points to known ones."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def optimal_assignment(cost: ArrayLike) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Rows and columns of the assignment of least total ``cost`` (scipy's Hungarian method,
    imported here so that loading perception does not pay for scipy.optimize)."""
    from scipy.optimize import linear_sum_assignment

    return linear_sum_assignment(cost)
