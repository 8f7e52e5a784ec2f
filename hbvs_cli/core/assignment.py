"""The assignment of least total cost, which matches detected points to known ones."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def optimal_assignment(cost: ArrayLike) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Rows and columns of the assignment of least total ``cost`` (the Hungarian method,
    ``scipy.optimize.linear_sum_assignment``); a rectangular cost assigns the smaller side.

    scipy.optimize is imported here, not at the top: every ``hbvs`` command that loads
    perception would otherwise pay its import at start-up.
    """
    from scipy.optimize import linear_sum_assignment

    return linear_sum_assignment(cost)
