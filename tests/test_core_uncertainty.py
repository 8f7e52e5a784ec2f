"""The parts of the fit's uncertainty that the footage tests do not isolate: the growth of
the covariance for point errors correlated from frame to frame (core/bundle.py), and the
heading tolerance the gain suggestion carries (core/gains.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hbvs_cli.core.bundle import correlation_inflation
from hbvs_cli.core.gains import INTERVAL_SIGMAS, heading_tolerance


def test_independent_errors_are_not_inflated():
    """White noise over 200 frames of 8 coordinates: the factor is 1 (clamped) or barely above."""
    residuals = np.random.default_rng(3).normal(0.0, 1e-4, (200, 8))
    assert 1.0 <= correlation_inflation(residuals) < 1.15


def test_errors_correlated_over_frames_are_inflated_by_their_long_run_variance():
    """An AR(1) series with coefficient 0.8 has a long-run variance (1 + 0.8) / (1 - 0.8) = 9
    times its variance; Bartlett's weights to 1/8 of 4000 frames recover most of it."""
    rng = np.random.default_rng(5)
    noise = rng.normal(0.0, 1.0, (4000, 6))
    series = np.empty_like(noise)
    series[0] = noise[0]
    for k in range(1, len(noise)):
        series[k] = 0.8 * series[k - 1] + noise[k]
    assert 6.0 < correlation_inflation(series) < 9.5  # measured 6.9


def test_few_frames_or_no_spread_give_no_inflation():
    assert correlation_inflation(np.ones((5, 4))) == 1.0
    assert correlation_inflation(np.zeros((40, 4))) == 1.0


def test_heading_tolerance_is_the_default_or_the_interval():
    assert heading_tolerance(0.2, 0.05) == 0.2
    assert heading_tolerance(0.2, 0.5) == pytest.approx(INTERVAL_SIGMAS * 0.5)
    assert math.isnan(heading_tolerance(0.2, float("nan")))


def test_uncertain_normal_warning_names_both_known_geometry_options():
    """The warning is one line and names both ways of giving the target's geometry."""
    from hbvs_cli.core.desired import UNCERTAIN_NORMAL_WARNING

    line = UNCERTAIN_NORMAL_WARNING.format(sigma=1.234)
    assert "\n" not in line and "1.2 deg" in line
    assert "--target-size" in line and "--target-points FILE" in line
