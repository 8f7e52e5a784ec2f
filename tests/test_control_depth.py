"""The adaptive depth law under real noise (issue 25; docs/method.md "The depth in the filter").

A user rarely knows d* better than within 2x. With the state filter carrying 1/d* the
motion measures the depth, and the composite update law hands it to dhat; every run here is
``hbvs repeat --sim`` followed by ``hbvs report`` (the sweep's own runner: the verdict is the
report's), on the default teach and fit (d* = 4 m, lateral-gain law, the fit's gains).

The campaign (``pytest -m campaign tests/test_control_depth.py``): 0.5 px, points
perception, dhat(0)/d* in {0.25, 0.5, 1, 2, 3, 4}, offset_y in {-0.1, 0, 0.1} m,
offset_theta in {-5, 0, 5} deg, three seeds each (162 runs), and the same starts without
noise; with images perception (rendered and detected), the six depths from the default
start, one seed (6 runs). The default suite runs two of the points runs.

Smoothness: each run's RMS dv/dt is held to twice that of the noise-free run of the same
start and dhat(0), or to twice the smoothness baseline of issue 17 (the paper's loop on
exact points from the default start, no filter, 0.20 m/s^2) where that is larger: a start on the path
is so calm without noise (0.03 m/s^2) that the noise floor of the soft start's first seconds
(0.1-0.25 m/s^2) is several times it. Both ratios are printed (``pytest -s``).

Measured (campaign): points, 155 of 162 runs converged (95.7 %; 26, 26, 26, 26, 24, 27 of
27 per depth), none stopped, dhat 3.960-4.097 m at the end, worst final position 1.02 cm
(one of the seven runs the verdict fails), RMS dv/dt at most 1.16 times its bound (within
2x of the same start's noise-free run in 80 % of runs); images, the same 54 starts once
each: 52 of 54 converged (96.3 %; the two others from d* and 2 d*), none stopped, dhat
3.969-4.058 m, worst position 0.52 cm, RMS dv/dt at most 1.28 times its bound.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from conftest import SUITE_OR_CAMPAIGN, campaign_extent

D_STAR = 4.0
FACTORS = (0.25, 0.5, 1.0, 2.0, 3.0, 4.0)
OFFSETS_Y = (-0.1, 0.0, 0.1)
OFFSETS_THETA = (-5.0, 0.0, 5.0)
#: The default suite's subset: the extreme depths from the corners of the start box.
SUBSET = ((0.25, 0.1, -5.0), (4.0, -0.1, 5.0))


def run_row(fit_path, *, dhat0_factor, offset_y=0.05, offset_theta=2.0, seed=0, pixel_noise=0.5, perception="points", **options):
    """One ``repeat --sim`` and its report, as a sweep row (verdict, errors, dhat, smoothness)."""
    from hbvs_cli.stages.sweep_run import RunTask, execute_run

    arguments = dict(sim=True, perception=perception, pixel_noise=pixel_noise, seed=seed,
                     dhat0=dhat0_factor * D_STAR, offset=f"-0.1,{offset_y},{offset_theta}", **options)
    row = execute_run(RunTask(fit_path=str(fit_path), index=0, point=0, repeat=0, seed=seed, values={},
                              arguments=arguments, command="", keep_path=None))
    assert row["status"] in ("ok", "stopped"), row["error"]
    return row


@pytest.fixture(scope="module")
def fit_path(default_fit):
    return default_fit[0]


@pytest.fixture(scope="module")
def smoothness_baseline(fit_path):
    """RMS dv/dt of the paper's loop (no filter, the raw measurement each frame; the default
    law) on exact points from the default start (m/s^2): issue 17's smoothness baseline,
    0.20 m/s^2."""
    return run_row(fit_path, dhat0_factor=1.0, pixel_noise=0.0, state_filter="none")["dv_dt_rms_mps2"]


def check_campaign(fit_path, starts, seeds, baseline, perception, capsys):
    rows, ratios, own_ratios = [], [], []
    for index, ((factor, offset_y, offset_theta), seed) in enumerate(itertools.product(starts, seeds)):
        start = dict(dhat0_factor=factor, offset_y=offset_y, offset_theta=offset_theta, perception=perception)
        row = run_row(fit_path, seed=1000 * seed + index, **start)
        clean = run_row(fit_path, pixel_noise=0.0, **start) if seed == seeds[0] else clean
        rows.append(row)
        own_ratios.append(row["dv_dt_rms_mps2"] / clean["dv_dt_rms_mps2"])
        ratios.append(row["dv_dt_rms_mps2"] / max(clean["dv_dt_rms_mps2"], baseline))
    converged = np.array([bool(row["converged"]) for row in rows])
    dhat = np.array([row["dhat_final_m"] for row in rows])
    with capsys.disabled():
        print(f"\n{perception}, 0.5 px, {len(rows)} runs: converged {converged.sum()} ({100 * converged.mean():.1f} %), "
              f"stopped {sum(row['status'] != 'ok' for row in rows)}, dhat final {dhat.min():.3f}-{dhat.max():.3f} m, "
              f"position max {100 * max(row['final_position_m'] for row in rows):.2f} cm, "
              f"RMS dv/dt max {max(row['dv_dt_rms_mps2'] for row in rows):.3f} m/s^2; "
              f"ratio to the bound max {max(ratios):.2f}, to the same start's noise-free run max {max(own_ratios):.2f} "
              f"(within 2x: {100 * np.mean(np.array(own_ratios) <= 2.0):.0f} %)")
        for factor in sorted({start[0] for start in starts}):
            chosen = [row for row, (start, _) in zip(rows, itertools.product(starts, seeds)) if start[0] == factor]
            print(f"  dhat(0) = {factor:g} d*: {sum(bool(r['converged']) for r in chosen)} / {len(chosen)} converged")
    return rows, converged, ratios


@SUITE_OR_CAMPAIGN
def test_the_depth_is_learnt_from_four_times_off_either_way(request, extent, fit_path, smoothness_baseline, capsys):
    whole = campaign_extent(request, extent)
    starts = list(itertools.product(FACTORS, OFFSETS_Y, OFFSETS_THETA)) if whole else list(SUBSET)
    rows, converged, ratios = check_campaign(fit_path, starts, (1, 2, 3) if whole else (1,), smoothness_baseline, "points", capsys)
    assert all(row["status"] == "ok" for row in rows)               # none stopped for a lost target
    assert converged.mean() >= 0.95 if whole else converged.all()
    assert max(ratios) <= 2.0
    for row in rows:
        # Measured: dhat ends within 2.5 % of d* from every start (3.96-4.10 m), and 1.02 cm
        # from the taught path at worst (a run that fails on heading).
        assert abs(row["dhat_final_m"] - D_STAR) < 0.03 * D_STAR
        assert row["final_position_m"] < 0.0125


@pytest.mark.campaign
def test_the_depth_is_learnt_with_images_in_the_loop(request, fit_path, smoothness_baseline, capsys):
    campaign_extent(request, "campaign")
    starts = list(itertools.product(FACTORS, OFFSETS_Y, OFFSETS_THETA))
    rows, converged, ratios = check_campaign(fit_path, starts, (1,), smoothness_baseline, "images", capsys)
    assert all(row["status"] == "ok" for row in rows)
    assert converged.mean() >= 0.95
    assert max(ratios) <= 2.0


def test_the_report_says_how_dhat_learnt(fit_path, tmp_path):
    """dhat(0) = 4 d*: the report gives the time to come within 10 % of d* and no warning;
    the paper's law without the filter, which learns at (31)'s rate only, is still moving."""
    from conftest import make_run

    from hbvs_cli.io.run_file import read_run
    from hbvs_cli.report.build import build_report

    common = dict(sim=True, perception="points", pixel_noise=0.5, dhat0=4 * D_STAR)
    make_run(fit_path, tmp_path / "new.mcap", **common)
    make_run(fit_path, tmp_path / "paper.mcap", law="paper", state_filter="none", **common)
    new, paper = (build_report(read_run(tmp_path / f"{name}.mcap")).depth for name in ("new", "paper"))
    # Measured: within 10 % after 4.7 s, drift at the end 0.46 % per second (the warning
    # starts at 0.5: the pull is eased while the heading still settles).
    assert new.learning_reference == "d_true" and 1.0 < new.learning_time_s < 8.0
    assert new.still_moving is False and new.warning is None
    # Measured: 16 m -> 9.2 m, falling 3.7 % of d* per second at the end.
    assert paper.learning_time_s is None and paper.still_moving is True
    assert paper.end_rate_per_s < -0.01 and "still moving" in paper.warning


def test_the_pull_is_eased_on_the_lateral_error_only_once_dhat_has_met_the_depth():
    """scheduled_depth_pull: the full rate until dhat has met d_f, then halved at a lateral
    error l = sqrt(k_2 ebar2^2 + e3^2) of lateral_settled; never negative, so the composite
    law's V_dot term -(kappa / gamma_1) d~^2 stays <= 0 (docs/method.md)."""
    import math

    from hbvs_cli.core.state_filter import FilterSettings, scheduled_depth_pull

    settings = FilterSettings()
    l0, k_2 = settings.lateral_settled, 400.0
    assert scheduled_depth_pull(0.8, 0.0, 0.05, k_2, settings, met=False) == 0.8
    assert scheduled_depth_pull(0.8, 0.0, 0.0, k_2, settings, met=True) == 0.8
    assert scheduled_depth_pull(0.8, 0.0, l0, k_2, settings, met=True) == pytest.approx(0.4)
    assert scheduled_depth_pull(0.8, l0 / math.sqrt(k_2), 0.0, k_2, settings, met=True) == pytest.approx(0.4)
    rng = np.random.default_rng(25)
    for _ in range(200):
        pull, ebar2, e3 = rng.uniform(0.0, 2.0), rng.normal(0.0, 0.05), rng.normal(0.0, 0.1)
        kappa = scheduled_depth_pull(pull, ebar2, e3, k_2, settings, met=bool(rng.integers(2)))
        assert 0.0 <= kappa <= pull
