"""Issue 47, layer 1: simulated routes longer than one view (sim/route.py, teach --sim --route)."""

from __future__ import annotations

import numpy as np
import pytest

from hbvs_cli.core.frames import world_to_robot
from hbvs_cli.io.teach_file import TeachReader
from hbvs_cli.sim.render import RenderSettings, SceneRenderer
from hbvs_cli.sim.route_world import RouteRenderer, corridor_route, route_targets_from_description

from conftest import call_hbvs


def _taught_poses(route, step_s: float = 0.25):
    times = np.arange(0.0, route.profile.duration, step_s)
    return times, route.profile.poses_at(times, route.start_pose)


def test_each_placed_target_projects_as_its_own_single_target_world():
    """A target placed in the route frame and seen from a route pose is, in F, exactly what its
    own World sees from the pose expressed in its frame W_i (the placement is a rigid motion)."""
    route = corridor_route()
    rng = np.random.default_rng(47)
    poses = np.column_stack([rng.uniform(0, 15, 20), rng.uniform(-1, 8, 20), rng.uniform(-np.pi, np.pi, 20)])
    worst = 0.0
    for index, (world, placed) in enumerate(zip(route.worlds, route.route_targets)):
        for pose in poses:
            in_route = world_to_robot(placed.points_world, pose, route.camera_height)
            own = world.points_in_camera(route.local_pose(index, pose))
            worst = max(worst, float(np.max(np.abs(in_route - own))))
    assert worst < 1e-12


def test_the_corridor_is_a_20_m_route_that_turns_always_seeing_a_target_each_overlapping_the_next():
    route = corridor_route()
    times, poses = _taught_poses(route)
    v, _ = route.profile.commands_at(times)
    length = float(np.sum(np.diff(np.append(route.profile.t, route.profile.t_end)) * route.profile.v))
    assert length >= 20.0
    assert np.degrees(poses[-1, 2] - poses[0, 2]) == pytest.approx(75.0, abs=1e-9)
    kinds = [world.target.kind for world in route.worlds]
    assert kinds == ["dots", "aruco", "texture", "texture"]
    # Each target wholly in view (all its points in front of the camera and in the image) from each pose.
    visible = np.array([[world.in_view(route.local_pose(i, pose)) for i, world in enumerate(route.worlds)]
                        for pose in poses])
    assert visible.any(axis=1).all(), "some taught instant sees no whole target"
    # Consecutive targets are seen together for a while (what a transition is estimated from),
    # and each next one is still in view when the one before leaves for good.
    for index in range(len(kinds) - 1):
        together = visible[:, index] & visible[:, index + 1]
        assert together.sum() * 0.25 >= 1.0
        last_seen = np.flatnonzero(visible[:, index])[-1]
        assert visible[last_seen, index + 1]
    assert visible[-1, -1] and visible[0, 0]


def test_the_route_renderer_draws_each_poster_as_the_single_target_renderer_does():
    """Noiseless frames: wherever only one poster is drawn, the route's frame equals that
    target's own renderer's frame from the pose in its frame (the same warp, the same pixels)."""
    route = corridor_route()
    settings = RenderSettings(noise_std=0.0)
    renderer = RouteRenderer(route, settings)
    _, poses = _taught_poses(route, 5.0)
    compared = 0
    for pose in poses:
        frame = renderer.render_scene(pose)
        alone = [SceneRenderer(world, part.raster, settings).render_scene(route.local_pose(index, pose))
                 for index, (world, part) in enumerate(zip(route.worlds, renderer.parts))]
        drawn = [image != int(settings.background) for image in alone]
        # A poster's patch carries a few pixels of wall around it: keep clear of the others' boxes.
        reach = []
        for mask in drawn:
            box = np.zeros_like(mask)
            rows, columns = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
            if rows.size:
                box[max(rows[0] - 4, 0):rows[-1] + 5, max(columns[0] - 4, 0):columns[-1] + 5] = True
            reach.append(box)
        for index, mask in enumerate(drawn):
            only = mask & ~np.any([box for other, box in enumerate(reach) if other != index], axis=0)
            assert np.array_equal(frame[only], alone[index][only])
            compared += int(only.sum())
    assert compared > 50_000

def test_teach_sim_route_corridor_records_the_route_and_its_targets(tmp_path):
    output = tmp_path / "route.mcap"
    result = call_hbvs("teach", "--sim", "--route", "corridor", "--fps", "1", "--duration", "12", "-o", str(output))
    assert result.returncode == 0, result.stderr
    reader = TeachReader(str(output))
    frames = list(reader.frames())
    assert len(frames) == 12
    settings = reader.info["settings"]
    assert settings["route"] == "corridor" and "target" not in settings and "path" not in settings
    placements, worlds = route_targets_from_description(reader.world_description)
    route = corridor_route()
    assert np.array_equal(placements, route.placements)
    assert [w.to_dict()["target"] for w in worlds] == [w.to_dict()["target"] for w in route.worlds]
    # The recorded poses are the route's taught drive.
    poses = np.array([frame.pose for frame in frames])
    expected = route.profile.poses_at(np.arange(12.0), route.start_pose)
    assert np.max(np.abs(poses - expected)) < 1e-9


@pytest.mark.parametrize("extra, message", [
    (("--target", "aruco"), "--route brings its own path and targets: leave out --target"),
    (("--path", "arc"), "leave out --path"),
    (("--route", "hallway"), "unknown route 'hallway'"),
])
def test_teach_route_refuses_what_it_brings_itself(tmp_path, extra, message):
    output = tmp_path / "route.mcap"
    result = call_hbvs("teach", "--sim", "--route", "corridor", *extra, "-o", str(output))
    assert result.returncode != 0 and message in result.stderr.decode() and b"Traceback" not in result.stderr
    assert not output.exists()


def test_fit_on_a_route_too_short_for_its_segment_says_which_and_writes_nothing(tmp_path):
    teach, fit = tmp_path / "route.mcap", tmp_path / "fit.mcap"
    assert call_hbvs("teach", "--sim", "--route", "corridor", "--fps", "1", "--duration", "3", "-o", str(teach)).returncode == 0
    result = call_hbvs("fit", str(teach), "-o", str(fit))
    assert result.returncode != 0 and "(segment 1): the target was found in only 3 of 3 frames" in result.stderr.decode()
    assert not fit.exists()
