"""``repeat --live`` on a base with dynamics (issue 43): ``robot-sim --base small`` obeys a
command through a 0.12 s motor lag, a 0.6 m/s^2 ramp and 0.26 m/s, 1.8 rad/s limits. hbvs,
told the same limits and lag, ends within 2 cm and 0.5 deg of the taught end pose, its
commands inside the limits and its depth estimate where it started (the lag is not read as
depth). The default suite drives at twice the taught pace; ``pytest -m campaign
tests/test_live_base.py`` drives the whole trajectory at its pace three times.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from hbvs_cli.core.simulator import ActuatorLimits  # noqa: E402
from hbvs_cli.io.run_file import read_run  # noqa: E402
from test_live_loop import dds_env, drive_stand_in  # noqa: E402

#: robot-sim's ``small`` base, as repeat is told it.
LIMITS = {"--max-v": 0.26, "--max-w": 1.8, "--max-accel": 0.6, "--base-lag": 0.12}
#: The sample fit's true depth d* (m).
D_STAR = 4.0


def drive_small_base(tmp_path, speed: float) -> tuple[float, float, object]:
    options = [str(x) for pair in LIMITS.items() for x in pair]
    position, heading = drive_stand_in(dds_env(), tmp_path, speed, ["--base", "small"], options)
    return position, heading, read_run(tmp_path / "live.mcap")


def assert_within_bounds(position: float, heading: float, run) -> None:
    v, w, t = run.state["v_c"], run.state["w_c"], run.state["t"]
    dhat = run.state["dhat"]
    print(f"final {100 * position:.2f} cm, {heading:.3f} deg; |v| <= {np.max(np.abs(v)):.3f}, |w| <= {np.max(np.abs(w)):.3f}; "
          f"dhat {dhat[0]:.3f} -> {dhat[-1]:.3f} (max {np.max(dhat):.3f})")
    assert position <= 0.02 and heading <= 0.5
    assert np.all(np.abs(v) <= LIMITS["--max-v"] + 1e-9) and np.all(np.abs(w) <= LIMITS["--max-w"] + 1e-9)
    rate = np.abs(np.diff(v)) / np.maximum(np.diff(t), 1e-9)
    # A step's command changes by at most max_accel times the period it is held for (5 periods at most).
    assert np.all(np.abs(np.diff(v)) <= LIMITS["--max-accel"] * 5 * 0.1 + 1e-9), rate.max()
    assert np.max(np.abs(dhat - D_STAR)) <= 0.1 * D_STAR


def test_a_base_with_lag_and_limits_converges_at_twice_the_pace(tmp_path):
    assert_within_bounds(*drive_small_base(tmp_path, 2.0))


@pytest.mark.campaign
@pytest.mark.parametrize("run", range(3))
def test_a_base_with_lag_and_limits_converges_over_the_whole_trajectory(tmp_path, run, request):
    if "campaign" not in (request.config.option.markexpr or ""):
        pytest.skip("runs with: pytest -m campaign tests/test_live_base.py")
    assert_within_bounds(*drive_small_base(tmp_path, 1.0))


def test_the_drive_model_averages_a_first_order_lag_exactly():
    limits = ActuatorLimits(lag_s=0.12)
    mean, end = limits.executed((0.0, 0.0), (0.2, 0.1), 0.12)
    assert end == pytest.approx((0.2 * (1 - math.exp(-1)), 0.1 * (1 - math.exp(-1))), rel=1e-12)
    # The mean over the period is the integral of c (1 - exp(-t / tau)) over it, divided by it.
    assert mean[0] == pytest.approx(0.2 * (1 - (1 - math.exp(-1))), rel=1e-12)
    assert ActuatorLimits().executed((0.5, 0.5), (0.2, 0.1), 0.1) == ((0.2, 0.1), (0.2, 0.1))
