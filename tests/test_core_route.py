"""Issue 47, layer 2's method: a route's segments and the transition between two (core/route.py),
against the exact geometry of the simulated corridor (sim/route.py)."""

from __future__ import annotations

import numpy as np
import pytest

from hbvs_cli.core.frames import wrap_angle
from hbvs_cli.core.route import Segment, bridge_brief_gaps, estimate_transition, split_route
from hbvs_cli.errors import MalformedDataError
from hbvs_cli.sim.route_world import MIN_SPAN_PX, corridor_route

from conftest import campaign_extent
from oracles import fit_route, ground_truth, taught_views

#: Frame rate (Hz) at which the corridor is sampled here.
RATE = 10.0


def overlap_frames(segment: Segment) -> slice:
    """The frames a (later) segment shares with the previous one."""
    return slice(segment.first, segment.overlap_last + 1)


def corridor_drive():
    route = corridor_route()
    times = np.arange(0.0, route.profile.duration, 1.0 / RATE)
    poses = route.profile.poses_at(times, route.start_pose)
    spans = np.array([route.spans(pose) for pose in poses])
    return route, poses, spans >= MIN_SPAN_PX, spans


def signals(route, index: int, poses, reference_pose):
    """The true theta (K,) and x_h (K, 2) of ``poses`` against F* at ``reference_pose`` for target ``index``, (4), (14)."""
    world = route.worlds[index]
    return ground_truth(world, route.local_pose(index, poses), route.local_pose(index, reference_pose))


def depth(route, index: int, reference_pose) -> float:
    return route.worlds[index].reference_geometry(route.local_pose(index, reference_pose))[2]


def test_split_route_follows_each_target_until_it_leaves_overlapping_the_next():
    visible = np.array([
        [1, 1, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1], [0, 0, 1], [0, 0, 1],
    ], dtype=bool)
    assert split_route(visible) == [Segment(1, 0, 3), Segment(2, 2, 5, overlap_last=3)]
    # Seen largest at the switch rather than longest in view: target 0 first.
    sizes = np.array([[90, 50, 0], [95, 52, 0], [99, 60, 40], [0, 70, 45], [0, 0, 50], [0, 0, 60]], dtype=float)
    assert split_route(visible, sizes) == [Segment(0, 0, 2), Segment(1, 1, 3, overlap_last=2), Segment(2, 2, 5, overlap_last=3)]
    with pytest.raises(MalformedDataError, match="gap"):
        split_route(np.array([[1, 0], [0, 0], [0, 1]], dtype=bool))
    with pytest.raises(MalformedDataError, match="first frame"):
        split_route(np.array([[0, 0], [1, 0]], dtype=bool))


def test_the_corridor_splits_into_its_four_targets_in_order():
    route, _, visible, spans = corridor_drive()
    segments = split_route(visible, spans)
    assert [s.target for s in segments] == [0, 1, 2, 3]
    assert segments[0].first == 0 and segments[-1].last == len(visible) - 1
    for previous, segment in zip(segments, segments[1:]):
        assert segment.first <= previous.last == segment.overlap_last
        both = visible[overlap_frames(segment), previous.target] & visible[overlap_frames(segment), segment.target]
        assert both.all() and both.size >= RATE  # at least a second seen together


def test_the_transition_is_exact_from_exact_signals_on_every_corridor_overlap():
    """From exact signals, rho = d*_{i+1}/d*_i, F*_{i+1}'s heading and origin / d*_i come out exact."""
    route, poses, visible, spans = corridor_drive()
    segments = split_route(visible, spans)
    for previous, segment in zip(segments, segments[1:]):
        reference, reference_next = poses[previous.first], poses[segment.first]
        overlap = poses[overlap_frames(segment)]
        theta_i, x_h_i = signals(route, previous.target, overlap, reference)
        theta_j, x_h_j = signals(route, segment.target, overlap, reference_next)
        transition = estimate_transition(theta_i, x_h_i, theta_j, x_h_j)
        d_i, d_j = depth(route, previous.target, reference), depth(route, segment.target, reference_next)
        true_heading = float(reference_next[2] - reference[2])
        c, s = np.cos(reference[2]), np.sin(reference[2])
        offset = reference_next[:2] - reference[:2]
        true_origin = np.array([c * offset[0] + s * offset[1], -s * offset[0] + c * offset[1]]) / d_i
        assert transition.depth_ratio == pytest.approx(d_j / d_i, rel=1e-9)
        assert transition.heading == pytest.approx(true_heading, abs=1e-9)
        np.testing.assert_allclose(transition.origin_over_depth, true_origin, atol=1e-9)
        assert transition.residual_rms < 1e-12
        assert transition.carried_depth(d_i) == pytest.approx(d_j, rel=1e-9)
        # A state filter's (theta, x_h, 1/d*) against F*_i, carried: the same pose against F*_{i+1}.
        for k in (0, overlap.shape[0] // 2, overlap.shape[0] - 1):
            carried, covariance = transition.carried_state((theta_i[k], *x_h_i[k], 1.0 / d_i), np.eye(4) * 1e-6)
            np.testing.assert_allclose(carried, (theta_j[k], *x_h_j[k], 1.0 / d_j), atol=1e-9)
            assert np.all(np.linalg.eigvalsh(covariance) > 0.0)


def test_the_transition_from_noisy_signals_is_within_its_reported_uncertainty():
    """Signals with the noise of a fit (1 mrad on theta, 1e-3 on x_h) over each corridor
    overlap, 20 seeds: rho's error within 3 of its reported sigmas in >= 90 % of the cases, and
    within 5 % of rho always."""
    route, poses, visible, spans = corridor_drive()
    segments = split_route(visible, spans)
    within, cases, worst = 0, 0, 0.0
    for previous, segment in zip(segments, segments[1:]):
        reference, reference_next = poses[previous.first], poses[segment.first]
        overlap = poses[overlap_frames(segment)]
        exact = (*signals(route, previous.target, overlap, reference), *signals(route, segment.target, overlap, reference_next))
        true_ratio = depth(route, segment.target, reference_next) / depth(route, previous.target, reference)
        for seed in range(20):
            rng = np.random.default_rng(seed)
            theta_i, x_h_i, theta_j, x_h_j = (value + rng.normal(0.0, 1e-3, np.shape(value)) for value in exact)
            transition = estimate_transition(theta_i, x_h_i, theta_j, x_h_j)
            error = transition.depth_ratio - true_ratio
            within += abs(error) <= 3.0 * transition.depth_ratio_std
            worst = max(worst, abs(error) / true_ratio)
            cases += 1
    assert within >= 0.9 * cases
    assert worst < 0.05


def test_errors_common_to_a_fits_frames_are_carried_into_the_transitions_uncertainty():
    """Each fit's signals over the corridor's three overlaps moved by errors common to its frames
    (6 random modes, constant, linear and quadratic over the overlap, ~1e-3 rad and 1e-3 in each
    channel, as :attr:`FitUncertainty.error_modes` states them), 200 seeds: the overlap's
    scatter shows little of it (a constant heading error leaves none), the modes carried through
    the least squares do. Measured: z-scores' RMS 0.93, 0.90, 0.94 for rho (max 2.8), 0.91,
    0.92, 0.81 for the heading (max 3.2; the scatter counts the quadratic part again); without
    the modes the heading's RMS z is 6.4, 4.9 and 3.2."""
    route, poses, visible, spans = corridor_drive()
    segments = split_route(visible, spans)
    rng = np.random.default_rng(7)
    for previous, segment in zip(segments, segments[1:]):
        reference, reference_next = poses[previous.first], poses[segment.first]
        overlap = poses[overlap_frames(segment)]
        exact = (*signals(route, previous.target, overlap, reference), *signals(route, segment.target, overlap, reference_next))
        true_ratio = depth(route, segment.target, reference_next) / depth(route, previous.target, reference)
        true_heading = float(reference_next[2] - reference[2])
        ramp = np.linspace(-1.0, 1.0, overlap.shape[0])[:, None, None]
        modes = [1e-3 * rng.normal(size=(1, 3, 6)) * ramp ** np.arange(3)[None, None, :].repeat(2, axis=2) for _ in range(2)]
        z_rho, z_heading, z_blind = [], [], []
        for seed in range(200):
            draw = np.random.default_rng(seed)
            moved = [m @ draw.normal(size=m.shape[2]) for m in modes]  # (K, 3) each
            theta_i, x_h_i = exact[0] + moved[0][:, 0], exact[1] + moved[0][:, 1:]
            theta_j, x_h_j = exact[2] + moved[1][:, 0], exact[3] + moved[1][:, 1:]
            transition = estimate_transition(theta_i, x_h_i, theta_j, x_h_j, *modes)
            blind = estimate_transition(theta_i, x_h_i, theta_j, x_h_j)
            z_rho.append((transition.depth_ratio - true_ratio) / transition.depth_ratio_std)
            z_heading.append((transition.heading - true_heading) / transition.heading_std)
            z_blind.append((blind.heading - true_heading) / blind.heading_std)
        assert 0.8 < np.sqrt(np.mean(np.square(z_rho))) < 1.1 and np.abs(z_rho).max() < 4.0
        assert 0.7 < np.sqrt(np.mean(np.square(z_heading))) < 1.1 and np.abs(z_heading).max() < 4.0
        assert np.sqrt(np.mean(np.square(z_blind))) > 2.5


def test_a_transition_needs_motion_and_two_frames():
    with pytest.raises(MalformedDataError, match="at least 2"):
        estimate_transition([0.0], [[0.1, 0.0]], [0.0], [[0.2, 0.0]])
    still = np.zeros(5)
    with pytest.raises(MalformedDataError, match="did not move"):
        estimate_transition(still, np.tile([0.1, 0.02], (5, 1)), still, np.tile([0.3, 0.01], (5, 1)))


def test_a_target_hidden_a_moment_is_bridged_and_one_flickering_out_of_view_is_not():
    """5 Hz, --max-gap 1 s: target 0 hidden 0.4 s (frames 10-11) and seen 2 s more is one
    stretch; target 1 seen again for one frame after a 0.6 s gap (it flickers as it leaves)
    keeps its gap; target 2's 1.2 s gap is longer than the spline bridges."""
    t = np.arange(30) * 0.2
    visible = np.zeros((30, 3), bool)
    visible[:, 0] = True
    visible[10:12, 0] = False
    visible[:15, 1] = True
    visible[18, 1] = True
    visible[:10, 2] = visible[16:, 2] = True
    filled = bridge_brief_gaps(visible, t, 1.0)
    assert filled[:, 0].all()
    assert np.array_equal(filled[:, 1:], visible[:, 1:])
    assert visible[10:12, 0].sum() == 0  # the input is left as it was
    segments = split_route(filled, None)
    assert [(s.target, s.first, s.last) for s in segments] == [(0, 0, 29)]


@pytest.mark.campaign
def test_fit_route_fits_each_segment_and_estimates_each_transition_from_half_pixel_noise(request):
    """The corridor at 5 Hz, its targets' exact pixels (where each is seen well) plus 0.5 px of
    noise. Over seeds 0-9 (measured when written): n* within 5.0 deg of the truth, x_hd1 within
    0.036 (each segment's median), rho within 38 % on the first switch (11 s of a straight
    drive, the board still small) and 5 % on the others; seed 0 is held to those bounds. 11 s."""
    campaign_extent(request, "campaign")
    route, times, poses, fitted = fitted_corridor(0.5, 0)
    assert [s.target for s in fitted.segments] == [0, 1, 2, 3]
    true_depths = []
    for segment, fit, reference in zip(fitted.segments, fitted.fits, fitted.references):
        assert segment.first <= reference <= segment.last
        world, reference_pose = route.worlds[segment.target], poses[reference]
        _, normal, d_star = world.reference_geometry(route.local_pose(segment.target, reference_pose))
        true_depths.append(d_star)
        assert np.degrees(np.arccos(np.clip(np.dot(fit.normal, normal), -1, 1))) < 5.0
        frames = slice(segment.first, segment.last + 1)
        _, x_h = signals(route, segment.target, poses[frames], reference_pose)
        assert np.median(np.abs(fit.trajectory.evaluate(times[frames]).x_hd1 - x_h[:, 0])) < 0.036
    bounds = [0.38, 0.05, 0.05]
    for transition, d_i, d_j, bound in zip(fitted.transitions, true_depths, true_depths[1:], bounds):
        assert abs(transition.depth_ratio / (d_j / d_i) - 1.0) < bound


def fitted_corridor(noise_px: float, seed: int):
    """The corridor at 5 Hz, its targets' exact pixels where each is seen well plus ``noise_px``
    of noise (seeded), split and fitted (:func:`fit_route`): the route, times, poses and fit."""
    route = corridor_route()
    times = np.arange(0.0, route.profile.duration, 0.2)
    poses, spans, pixels = taught_views(route, times, noise_px, np.random.default_rng(seed))
    fitted = fit_route(route, times, pixels, spans)
    return route, times, poses, fitted


def transition_z_scores(route, poses, fitted) -> list[tuple[float, float]]:
    """Each transition's (rho's, the heading's) error over its stated standard deviation, against
    the corridor's true d*_i and F*_i headings at the fit's reference frames ``poses[references]``."""
    references = [poses[frame] for frame in fitted.references]
    depths = [depth(route, segment.target, pose) for segment, pose in zip(fitted.segments, references)]
    return [((transition.depth_ratio - d_j / d_i) / transition.depth_ratio_std,
             float(wrap_angle(transition.heading - (after[2] - before[2]))) / transition.heading_std)
            for transition, d_i, d_j, before, after in zip(fitted.transitions, depths, depths[1:], references, references[1:])]


def assert_z_scores_honest(z_scores, count: int, rms_range=(0.6, 1.6), largest: float = 4.0) -> None:
    """At least ``count`` transitions' (rho, heading) z-scores, each column's RMS within ``rms_range``, none beyond ``largest``."""
    z = np.asarray(z_scores, dtype=float)
    assert z.shape == (z.shape[0], 2) and z.shape[0] >= count
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert np.all((rms_range[0] < rms) & (rms < rms_range[1])), rms
    assert np.abs(z).max() < largest


@pytest.mark.campaign
def test_the_transitions_stated_uncertainty_holds_both_ways_on_noisy_fits(request):
    """bench/route_corridor.py's fits (the corridor at 5 Hz, 0.1 px on the exact pixels), seeds
    0-9, 30 transitions: rho's and the heading's z-scores (error / stated sigma) with an RMS in
    0.6-1.6 and none beyond 4. Measured: RMS 0.60 (rho) and 1.09 (heading), largest 2.1 and 3.3
    (before: 0.39 and 1.39). The first transition (11 s of a straight drive, the board small)
    is rho's largest: 3.6 % low on average over the seeds, the regressor's noise pulling rho
    down (errors in variables). 20 s on 2 cores."""
    campaign_extent(request, "campaign")
    z_scores = []
    for seed in range(10):
        route, _, poses, fitted = fitted_corridor(0.1, seed)
        z_scores += transition_z_scores(route, poses, fitted)
    assert_z_scores_honest(z_scores, 30)
