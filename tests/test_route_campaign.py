"""Issue 47's bar on the simulated corridor (23 m, 4 targets, three 25 deg turns): the whole
pipeline, ``teach --sim --route corridor | fit | repeat --sim --pixel-noise 0.5 --seed S``,
ends within 2 cm and 0.5 deg of the taught end pose for >= 95 % of seeds 0-9. A campaign
(about 2 min on 2 cores): ``pytest -m campaign tests/test_route_campaign.py``."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from hbvs_cli.core.frames import wrap_angle
from hbvs_cli.io.run_file import read_run

from conftest import call_hbvs, campaign_extent

#: The repeat's seeds, its pixel noise (px, 1 sigma) and the bar: end pose within (m, deg), share of seeds.
SEEDS, PIXEL_NOISE, END_POSITION_M, END_HEADING_DEG, SHARE = range(10), "0.5", 0.02, 0.5, 0.95


@pytest.mark.campaign
def test_ten_seeds_at_half_a_pixel_end_on_the_taught_end_pose(request, tmp_path):
    """One teach and fit (teach's defaults: 30 Hz, rendered frames, the detectors), ten
    repeats from the default start offset. Measured: all 10 within 0.09-0.56 cm and
    0.001-0.149 deg (0.17-0.31 cm and 0.024-0.071 deg before the transitions' sigmas were made
    honest; 19 of seeds 0-19 before the hand-over, seed 15 losing the far board after the
    first switch), dhat within 0.7 % of every segment's true d* at its end, no frame lost."""
    campaign_extent(request, "campaign")
    teach, fit = tmp_path / "teach.mcap", tmp_path / "fit.mcap"
    assert call_hbvs("teach", "--sim", "--route", "corridor", "-o", str(teach)).returncode == 0
    assert call_hbvs("fit", str(teach), "-o", str(fit)).returncode == 0
    ends = []
    for seed in SEEDS:
        repeat = call_hbvs("repeat", "--sim", str(fit), "--pixel-noise", PIXEL_NOISE, "--seed", str(seed), "-o", "-")
        assert repeat.returncode == 0, repeat.stderr.decode()
        run = read_run(io.BytesIO(repeat.stdout))
        position = float(np.linalg.norm(run.true_pose[-1, :2] - run.desired_pose[-1, :2]))
        heading = abs(float(np.degrees(wrap_angle(run.true_pose[-1, 2] - run.desired_pose[-1, 2]))))
        report = json.loads(call_hbvs("report", "-", "--json", input=repeat.stdout).stdout)
        assert report["target"]["lost_frames"] == 0
        ends.append((position, heading, max(segment["relative_error"] for segment in report["route"])))
        print(f"seed {seed}: {100 * position:.2f} cm, {heading:.3f} deg, dhat within {100 * ends[-1][2]:.2f} % of d*_i")
    within = [position <= END_POSITION_M and heading <= END_HEADING_DEG for position, heading, _ in ends]
    assert sum(within) >= SHARE * len(SEEDS)
    assert max(depth for _, _, depth in ends) < 0.01
