"""core/gcv.py: the GCV criterion of the smoothing spline, against scipy's own spline."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import make_smoothing_spline

from hbvs_cli.core.gcv import gcv_criterion, gcv_smoothing


def _samples(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.02, 0.05, n))
    return t, np.sin(2.0 * t) + 0.3 * t + 0.01 * rng.standard_normal(n)


@pytest.mark.parametrize("n", [5, 6, 7, 40])
@pytest.mark.parametrize("lam", [1e-6, 1e-3, 0.05, 3.0])
def test_criterion_matches_the_dense_smoother_matrix(lam: float, n: int) -> None:
    """GCV = (|y - f|^2 / n) / (1 - tr A / n)^2, with A built column by column from
    scipy's spline of each unit vector (no banded algebra involved); from the fewest
    samples a spline takes (the trace's recursion starts and ends on the band's edges)."""
    t, y = _samples(n, seed=1)
    n = t.size
    smoother = np.column_stack([make_smoothing_spline(t, e, lam=lam)(t) for e in np.eye(n)])
    fitted = smoother @ y
    expected = (np.sum((y - fitted) ** 2) / n) / (1.0 - np.trace(smoother) / n) ** 2
    assert gcv_criterion(t, y)(lam) == pytest.approx(expected, rel=1e-8)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lambda_is_the_one_scipy_picks(seed: int) -> None:
    """The same criterion and search as scipy's make_smoothing_spline(t, y): the splines
    agree to well below the noise (the search stops within 1e-5 of a flat minimum)."""
    t, y = _samples(300, seed)
    lam = gcv_smoothing(t, y)
    ours = make_smoothing_spline(t, y, lam=lam)(t)
    scipys = make_smoothing_spline(t, y)(t)
    assert np.max(np.abs(ours - scipys)) < 1e-6
    assert 0.0 < lam < t.size
