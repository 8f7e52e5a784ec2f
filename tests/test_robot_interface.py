"""A robot interface added from outside the package (issue 45): ``repeat --live`` drives a toy robot
that lives in this process, through the same loop, checks and run file as a ROS 2 or an MJPEG one.

The toy is hbvs's simulated world (robot-sim's: :func:`~hbvs_cli.sim.stand_in.stand_in_world`) rendered
at the pose its received commands drove a kinematic unicycle to, on a virtual clock: each frame asked
for is one taught frame period later, so the run takes as long as its computing, not the drive's 20 s. Registering it touches no file of hbvs_cli;
a shipped one would touch two (its module, and its registration in stages/live.py).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from hbvs_cli.core.frames import compose_planar_pose
from hbvs_cli.core.unicycle import DynamicBase
from hbvs_cli.errors import UsageError
from hbvs_cli.io.fit_file import read_fit_file
from hbvs_cli.io.run_file import read_run
from hbvs_cli.io.sources.frame_source import LiveFrame
from hbvs_cli.settings.commands import DEFAULT_OFFSET
from hbvs_cli.sim.stand_in import stand_in_world
from hbvs_cli.stages import live
from hbvs_cli.stages.frame_decoding import fit_reference_image
from hbvs_cli.stages.options import parse_offset

from conftest import call_hbvs

#: ``--camera toy:`` chooses the toy (the OpenCV camera would refuse the name).
TOY_SCHEME = "toy:"


class ToyRobot:
    """An in-process robot: a :class:`~hbvs_cli.stages.live.LiveSource` and a
    :class:`~hbvs_cli.stages.live.CommandSink` at once."""

    topic = "toy/cmd_vel"

    def __init__(self, fit_path: str, offset: tuple[float, float, float]) -> None:
        fit = read_fit_file(fit_path)
        self.camera = fit.model.camera
        self.scene, self.renderer, taught_start = stand_in_world(fit.model, fit_reference_image(fit), None, fit_path)
        self.period = fit.model.taught_frame_interval()
        self.pose = tuple(float(v) for v in compose_planar_pose(taught_start, offset))
        self.base = DynamicBase()  # kinematic: obeys at once
        self.rng = np.random.default_rng(7)
        self.command = (0.0, 0.0)
        self.commands: list[tuple[float, float]] = []
        self.frames = 0
        self.origin = time.monotonic()

    def latest(self, timeout_s: float) -> LiveFrame:
        """The next frame, one period after the last, the command since then carried out."""
        if self.frames:
            self.pose = self.base.advance(self.pose, self.command, self.period)
        self.frames += 1
        stamp = self.frames * self.period
        # Arrival on the virtual clock too: the camera clock sees a frame with no delay.
        return LiveFrame(self.renderer.render(np.array(self.pose), self.rng), stamp, self.origin + stamp, 0)

    def publish(self, v: float, w: float) -> None:
        self.command = (v, w)
        self.commands.append(self.command)

    def other_publishers(self) -> int:
        return 0

    def foreign_commands(self) -> int:
        return 0


@pytest.fixture
def toy_interface():
    """The toy registered for the test, and the robots it opened."""
    robots: list[ToyRobot] = []

    def open_toy(options, stack, lost_timeout, info):
        robots.append(ToyRobot(options.input, parse_offset(DEFAULT_OFFSET)))
        return live.RobotLink(robots[-1], lambda: (robots[-1], robots[-1].camera), options.camera)

    interface = live.RobotInterface("toy", lambda options: (options.camera or "").startswith(TOY_SCHEME), open_toy)
    live.register_robot_interface(interface)
    yield robots
    live.ROBOT_INTERFACES.remove(interface)


def test_a_robot_interface_registered_from_outside_the_package_drives_repeat_live_to_convergence(
        toy_interface, default_fit, tmp_path):
    fit_path, model = default_fit
    run_path = tmp_path / "run.mcap"
    # The toy's clock is virtual: a stall of a busy test machine is no stale camera (the deadman waits 10 s).
    result = call_hbvs("repeat", str(fit_path), "--live", "--camera", TOY_SCHEME, "--stale-timeout", "10", "--lost-timeout", "10",
                       "-o", str(run_path), "-q")
    assert result.returncode == 0, result.stderr.decode()
    robot, = toy_interface
    run = read_run(run_path)
    assert run.info["mode"] == "live" and run.info["live"]["source"] == TOY_SCHEME
    assert run.info["live"]["cmd_topic"] == ToyRobot.topic
    # Every command of the run reached the toy, and the last ones stopped it.
    assert robot.commands[-1] == (0.0, 0.0) and len(robot.commands) > run.steps
    # Started 11 cm and 2 deg off the taught start, it ends on the taught path (measured: e1 9e-5, e2 1.1e-4,
    # e3 -0.011 deg (19); the toy's true pose 3.2 mm and 0.09 deg from the taught end pose).
    assert run.steps == 600  # the whole 20 s drive at 30 Hz
    final = {name: float(run.state[name][-1]) for name in ("e1", "e2", "e3")}
    assert abs(final["e1"]) < 1e-3 and abs(final["e2"]) < 1e-3 and abs(math.degrees(final["e3"])) < 0.1, final
    taught_end = robot.scene.taught_pose_at_run_time(float(run.state["t"][-1]))
    assert math.hypot(robot.pose[0] - taught_end[0], robot.pose[1] - taught_end[1]) < 0.01
    assert abs(math.degrees(math.remainder(robot.pose[2] - taught_end[2], 2 * math.pi))) < 0.2


def test_the_shipped_robot_interfaces_are_chosen_by_their_options():
    from hbvs_cli.settings.commands import RepeatOptions

    def chosen(**given):
        return live.robot_interface(RepeatOptions(input="fit.mcap", live=True, **given)).name

    assert chosen(camera="0") == "camera" and chosen(ros2_image="/camera/image_raw") == "ros2"
    for neither_or_both in ({}, {"camera": "0", "ros2_image": "/camera/image_raw"}):
        with pytest.raises(UsageError, match="--live needs one frame source"):
            live.check_live_options(RepeatOptions(input="fit.mcap", live=True, **neither_or_both), 3.0)
