"""The smoothing spline's lambda by generalised cross-validation in O(n) per trial: scipy's
``make_smoothing_spline(lam=None)`` criterion, minimiser and bounds without its per-sample
Python loops, in Reinsch's banded form (Green and Silverman, 1994, Sec. 2.3, 3.3)::

    GCV(lambda) = (|y - f|^2 / n) / (1 - tr A(lambda) / n)^2
    y - f = lambda Q gamma,   n - tr A = lambda tr(M^-1 Q^T Q),   M = R + lambda Q^T Q,   gamma = M^-1 Q^T y

with Q (n x (n-2)) and R ((n-2) x (n-2), tridiagonal) of the book. Only the five central
bands of M^-1 enter the trace; they follow from the Cholesky factor by the recursion of
Hutchinson and de Hoog (Numerische Mathematik 47, 1985, 99-106).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numpy.typing import NDArray


def gcv_criterion(t: NDArray[np.float64], y: NDArray[np.float64]) -> Callable[[float], float]:
    """The GCV criterion of a cubic smoothing spline of ``(t, y)``, ``t`` (n,) strictly
    increasing (s), n >= 5, as a function of scipy's ``lam`` (s^3)."""
    from scipy.linalg import cho_solve_banded, cholesky_banded

    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n = t.size
    h = np.diff(t)
    inverse = 1.0 / h
    # Q^T, row j (j = 0..n-3): columns j, j+1, j+2 hold a_j, b_j, c_j.
    a, c = inverse[:-1], inverse[1:]
    b = -(a + c)
    # The bands of Q^T Q (pentadiagonal, symmetric) and of R (tridiagonal), upper banded
    # storage as LAPACK keeps it: row 2 the diagonal, row 1 the first superdiagonal
    # (shifted by one), row 0 the second (shifted by two).
    qtq = np.zeros((3, n - 2))
    qtq[2] = a * a + b * b + c * c
    qtq[1, 1:] = b[:-1] * a[1:] + c[:-1] * b[1:]
    qtq[0, 2:] = c[:-2] * a[2:]
    r = np.zeros((3, n - 2))
    r[2] = (h[:-1] + h[1:]) / 3.0
    r[1, 1:] = h[1:-1] / 6.0
    qty = a * y[:-2] + b * y[1:-1] + c * y[2:]
    # The trace's weights: the diagonal once, each off-diagonal twice (symmetry).
    weights = (qtq[2].tolist(), (2.0 * qtq[1]).tolist(), (2.0 * qtq[0]).tolist())

    def criterion(lam: float) -> float:
        lam = float(lam)
        factor = cholesky_banded(r + lam * qtq, lower=False)
        gamma = cho_solve_banded((factor, False), qty)
        q_gamma = np.zeros(n)
        q_gamma[:-2] += a * gamma
        q_gamma[1:-1] += b * gamma
        q_gamma[2:] += c * gamma
        residual_sq = lam * lam * float(q_gamma @ q_gamma)
        trace = lam * _banded_inverse_trace(factor, weights)
        return (residual_sq / n) / (trace / n) ** 2

    return criterion


def _banded_inverse_trace(factor: NDArray[np.float64], weights: tuple[list[float], list[float], list[float]]) -> float:
    """``sum_ij S_ij P_ij`` over the five central bands, ``S = M^-1``, ``M = U^T U``: ``factor``
    is U in upper banded storage, ``weights`` P's three upper bands (off-diagonals doubled),
    same layout. By ``U S = U^-T``, row i of S's band follows from rows i+1 and i+2 (plain
    floats: numpy's per-element overhead would be most of the cost)."""
    diagonal, first, second = factor[2].tolist(), factor[1].tolist(), factor[0].tolist()
    p0, p1, p2 = weights
    m = len(diagonal)
    # Row i's entries right of the diagonal, U[i, i+1] and U[i, i+2] (and P's), zero past the last row: the
    # products with those zeros leave the sum as it was.
    right1, right2 = (first[1:] + [0.0])[:m], (second[2:] + [0.0, 0.0])[:m]
    w_right1, w_right2 = (p1[1:] + [0.0])[:m], (p2[2:] + [0.0, 0.0])[:m]
    total = 0.0
    s11 = s12 = s22 = 0.0  # S[i+1,i+1], S[i+1,i+2], S[i+2,i+2]
    for u0, u1, u2, w0, w1, w2 in zip(*(reversed(band) for band in (diagonal, right1, right2, p0, w_right1, w_right2))):
        s02 = -(u1 * s12 + u2 * s22) / u0
        s01 = -(u1 * s11 + u2 * s12) / u0
        s00 = (1.0 / u0 - u1 * s01 - u2 * s02) / u0
        total = total + s00 * w0 + s01 * w1 + s02 * w2
        s11, s12, s22 = s00, s01, s11
    return total


def gcv_smoothing(t: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    """The lambda scipy's ``make_smoothing_spline(t, y)`` chooses (to rounding): the GCV
    minimum over ``(0, n)`` by bounded Brent search; ValueError if it does not converge."""
    from scipy.optimize import minimize_scalar

    n = int(np.asarray(t).size)
    found = minimize_scalar(gcv_criterion(t, y), bounds=(0, n), method="bounded")
    if not found.success:
        raise ValueError(f"Unable to find minimum of the GCV function: {found.message}")
    return float(found.x)
