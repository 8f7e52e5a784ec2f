"""Issue 47, layer 3 in simulation: the controller segment by segment along the corridor
(sim/route_loop.py), through the one loop (run_servo)."""

from __future__ import annotations

import numpy as np
import pytest

from hbvs_cli.core.control_settings import ControllerGains
from hbvs_cli.core.controller import AdaptiveTrackingController
from hbvs_cli.core.frames import compose_planar_pose, wrap_angle
from hbvs_cli.core.gains import noise_from_residual, suggest_gains
from hbvs_cli.core.route import fit_route, split_route
from hbvs_cli.core.simulator import ActuatorLimits
from hbvs_cli.perception.target_kinds import target_kind
from hbvs_cli.settings.commands import DEFAULT_MAX_V, DEFAULT_MAX_W, DEFAULT_OFFSET
from hbvs_cli.sim.route_world import MIN_SPAN_PX, corridor_route
from hbvs_cli.sim.route_loop import RouteTrajectory, run_route, switch_times
from hbvs_cli.stages.options import parse_offset

#: The taught frames' period (s) and the control period (s).
TAUGHT_STEP = 0.4
DT = 1.0 / 30.0


@pytest.fixture(scope="module")
def exact_corridor():
    """The corridor, its taught drive and its route fit from its targets' exact pixels."""
    route = corridor_route()
    times = np.arange(0.0, route.profile.duration, TAUGHT_STEP)
    poses, spans, pixels = route.taught_views(times)
    fitted = fit_route(times, pixels, split_route(spans >= MIN_SPAN_PX, spans), route.camera, None, max_lost=0.5, max_gap=5.0,
                       errors=[target_kind(world.target.kind).errors for world in route.worlds], warn=lambda message: None)
    depths = [route.worlds[s.target].reference_geometry(route.local_pose(s.target, poses[r]))[2]
              for s, r in zip(fitted.segments, fitted.references)]
    return route, times, fitted, np.array(depths)


def test_the_route_trajectory_gives_each_segment_its_own_desired_signals(exact_corridor):
    route, times, fitted, _ = exact_corridor
    switches = switch_times(fitted, times)
    trajectory = RouteTrajectory([fit.trajectory for fit in fitted.fits], switches)
    probe = np.array([1.0, switches[0] + 0.5, switches[1] + 0.5, switches[2] + 0.5])
    together = trajectory.evaluate(probe)
    for k, t in enumerate(probe):
        alone = fitted.fits[k].trajectory.evaluate(t)
        assert together.theta_d[k] == alone.theta_d and together.x_hd1[k] == alone.x_hd1 and together.x_hd2[k] == alone.x_hd2
    assert float(trajectory.evaluate(1.0).x_hd1) == fitted.fits[0].trajectory.evaluate(1.0).x_hd1


def test_a_repeat_along_the_corridor_ends_on_the_taught_end_pose_switching_smoothly(exact_corridor):
    """Exact measurements, the fit's gains per segment, a state filter per segment, the default
    start offset and dhat(0) 20 % off: the robot ends within 2 cm and 0.5 deg of the taught pose
    of its last frame (measured 0.05 mm, 3e-5 deg), each switch carries dhat over by rho exactly, the commands
    step by less than 0.05 m/s and 0.05 rad/s at a switch (measured 0.001 and 0.0005), and
    from the second segment on dhat ends within 1 % of the true d*_i."""
    route, times, fitted, depths = exact_corridor
    gains = [suggest_gains(fit.condition.percentiles["p50"], noise_from_residual(fit.residual_px.rms, fit.m_ref.shape[0]),
                           fit.m_ref, fit.normal, route.camera.mean_focal).gains for fit in fitted.fits]
    noise = [noise_from_residual(fit.residual_px.rms, fit.m_ref.shape[0]) / route.camera.mean_focal for fit in fitted.fits]
    controller = AdaptiveTrackingController(ControllerGains(), dhat0=1.2 * depths[0])
    start = compose_planar_pose(route.start_pose, parse_offset(DEFAULT_OFFSET))
    switches = switch_times(fitted, times)
    camera, steps = run_route(route, fitted, switches, controller, start, DT, float(times[-1]) + DT,
                              ActuatorLimits(max_v=DEFAULT_MAX_V, max_w=DEFAULT_MAX_W), gains=gains, filter_noise=noise)
    records = list(steps)
    assert not any(record.lost for record in records)
    t = np.array([record.t for record in records])
    poses = np.array([record.pose for record in records])
    taught = route.profile.poses_at(t, route.start_pose)
    assert np.linalg.norm(poses[-1, :2] - taught[-1, :2]) < 0.02
    assert abs(np.degrees(wrap_angle(poses[-1, 2] - taught[-1, 2]))) < 0.5
    assert [segment for _, segment, _, _ in camera.switches] == [1, 2, 3]
    for (when, segment, before, after), transition in zip(camera.switches, fitted.transitions):
        assert after == pytest.approx(transition.carried_depth(before), rel=1e-12)
        k = int(np.searchsorted(t, when))
        assert abs(records[k].v_c - records[k - 1].v_c) < 0.05 and abs(records[k].w_c - records[k - 1].w_c) < 0.05
    in_force = np.searchsorted(switches, t, side="right")
    dhat = np.array([record.dhat for record in records])
    for segment in (1, 2, 3):
        last = np.flatnonzero(in_force == segment)[-1]
        assert dhat[last] == pytest.approx(depths[segment], rel=0.01)
