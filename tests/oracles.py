"""Ground truths and closed forms the tests compare hbvs against; nothing in hbvs_cli needs them."""

from __future__ import annotations

from dataclasses import fields
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hbvs_cli.core.bundle import _shape_bias_rows
from hbvs_cli.core.control_settings import ControllerGains
from hbvs_cli.core.controller import DesiredState, TrackingErrors
from hbvs_cli.core.decomposition import (FACING_PRIOR, PURE_ROTATION_TOLERANCE, PlanarMotion, homography_candidates,
                                         select_branch, take_branch)
from hbvs_cli.core.estimation import Observation, PlanarPoseEstimator
from hbvs_cli.core.desired import DesiredFit, fit_desired_trajectory
from hbvs_cli.core.fit_model import DetectorSpec
from hbvs_cli.core.frames import wrap_angle
from hbvs_cli.core.path import CommandProfile
from hbvs_cli.core.route import RouteFit, estimate_transitions, split_route, view_spans
from hbvs_cli.core.simulator import ActuatorLimits
from hbvs_cli.core.state_filter import _arc
from hbvs_cli.core.trajectory import _desired_state
from hbvs_cli.io.fit_file import read_fit_file
from hbvs_cli.io.mcap import McapMessage, McapWriter
from hbvs_cli.io.route_file import RouteFile, route_of
from hbvs_cli.perception import TargetDetector, target_kind
from hbvs_cli.report.result import RunReport
from hbvs_cli.sim.closed_loop import SimulatedRobot
from hbvs_cli.sim.route_world import MIN_SPAN_PX, RouteWorld
from hbvs_cli.sim.world import World


#: Top-level keys of a report's JSON, in order, but a live run's ``timing`` and a route's ``route``.
REPORT_KEYS = tuple(field.name for field in fields(RunReport) if field.name not in ("timing", "route"))


def closed_loop_error_rates(errors: TrackingErrors, d_tilde: float, x_h2: float, w_c: float, x_hd1_dot: float,
                            d_star: float, gains: ControllerGains) -> tuple[float, float, float]:
    """``(e1_dot, ebar2_dot, e3_dot)`` of the closed-loop error system (32) with k_2."""
    e1_dot = (-gains.k_v * errors.e1 + gains.k_2 * errors.ebar2 * w_c + d_tilde * (x_h2 * w_c - x_hd1_dot)) / d_star
    ebar2_dot = -(errors.e1 * w_c + x_hd1_dot * errors.e3)
    e3_dot = -gains.k_w * errors.e3 + gains.k_2 * x_hd1_dot * errors.ebar2
    return float(e1_dot), float(ebar2_dot), float(e3_dot)


def predict_state(state: ArrayLike, v: float, w: float, dt: float, depth: float) -> tuple[float, float, float]:
    """The state (theta, x_h1, x_h2) after holding (v, w) (m/s, rad/s) for dt (s) at the
    depth d* (m): (5), (23) integrated exactly."""
    theta, x1, x2 = (float(s) for s in state)
    dx, dy, c, s = _arc(v, w, dt)
    a, b = x1 - dx / depth, x2 - dy / depth
    return theta - w * dt, c * a + s * b, -s * a + c * b


def decompose_homography(H: ArrayLike, m_ref: ArrayLike, reference_normal: ArrayLike = FACING_PRIOR) -> PlanarMotion:
    """(theta, x_h, n*) of each homography, the normal chosen by :func:`select_branch`. With H at the
    scale sigma_2 = 1, ``R a = H a`` for the plane's directions a, b (orthonormal, ``a x b = n``), ``R n
    = H a x H b`` and ``t = (H - R) n`` (12); a pure rotation takes the reference normal (t = 0 whatever n)."""
    m_ref = np.asarray(m_ref, dtype=float)
    H = np.asarray(H, dtype=float)
    H = H / np.linalg.svd(H, compute_uv=False)[..., 1, None, None]
    candidates = homography_candidates(H)
    index, valid = select_branch(candidates, m_ref, reference_normal)
    n = take_branch(candidates.normals, index)
    pure_rotation = candidates.strength < PURE_ROTATION_TOLERANCE
    n = np.where(pure_rotation[..., None], np.broadcast_to(reference_normal, n.shape), n)
    a = np.cross(n, np.eye(3)[np.argmin(np.abs(n), axis=-1)])
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.cross(n, a)
    Ha, Hb = np.einsum("...ij,...j->...i", H, a), np.einsum("...ij,...j->...i", H, b)
    R = np.stack([Ha, Hb, np.cross(Ha, Hb)], axis=-1) @ np.swapaxes(np.stack([a, b, n], axis=-1), -1, -2)
    t = np.einsum("...ij,...j->...i", H - R, n)
    theta = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    planarity = np.abs(t[..., 2]) + np.abs(1.0 - R[..., 2, 2])
    return PlanarMotion(theta=theta, x_h=t[..., :2], normal=n, valid=valid, residual=planarity)


def relative_planar_pose(pose: ArrayLike, reference_pose: ArrayLike) -> tuple[NDArray[np.float64] | float, NDArray[np.float64]]:
    """``theta = phi* - phi`` wrapped to [-pi, pi) and ``x_f`` (..., 3) (m), (3)-(5), of F* at
    ``reference_pose`` ((3,) or (..., 3)) seen from ``pose`` (..., 3)."""
    pose = np.asarray(pose, dtype=float)
    reference_pose = np.asarray(reference_pose, dtype=float)
    dx = reference_pose[..., 0] - pose[..., 0]
    dy = reference_pose[..., 1] - pose[..., 1]
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    x_f = np.stack([c * dx + s * dy, -s * dx + c * dy, np.zeros_like(dx)], axis=-1)
    theta = wrap_angle(reference_pose[..., 2] - pose[..., 2])
    return theta, x_f


def ground_truth(world: World, pose: ArrayLike, reference_pose: ArrayLike) -> tuple[NDArray[np.float64] | float, NDArray[np.float64]]:
    """True theta (rad) and x_h = x_f / d* (..., 2) of F relative to F* in a simulated ``world``, (4), (14)."""
    theta, x_f = relative_planar_pose(pose, reference_pose)
    d_star = float(world.wall_x - np.asarray(reference_pose, dtype=float)[0])
    return theta, x_f[..., :2] / d_star


def target_size(world: World) -> float:
    """Largest distance between two of the ``world``'s target points (m): the target's metric size."""
    p = world.target.points_world
    return float(np.max(np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)))


def observe_normalized(estimator: PlanarPoseEstimator, m: ArrayLike) -> Observation:
    """The estimator's observation of normalised points of shape (N, 3) (no pixels, no lens)."""
    m = np.asarray(m, dtype=float)
    return estimator._observe(estimator.solver.solve_one((m[:, 1] / m[:, 0]).tolist(), (m[:, 2] / m[:, 0]).tolist()), None)


def copy_message(writer: McapWriter, message: McapMessage, log_time_ns: int | None = None,
                 data: bytes | None = None) -> None:
    """Write a message read from another file on ``writer``, on a channel declared as there, with its own
    bytes and log time unless others are given (tests that edit or retime a recording)."""
    channel_id = writer._declare(message.topic, message.schema_name, message.schema_encoding, message.schema_data,
                                 message.message_encoding)
    writer._add(channel_id, message.log_time if log_time_ns is None else log_time_ns, message.data if data is None else data)


def make_detector(kind: str, *, n_points: int, reference_image: np.ndarray | None = None, reference_pixels: ArrayLike | None = None,
                  seed: int = 0, windowed: bool = False, **options) -> TargetDetector:
    """A detector of ``n_points`` points for a registered ``kind``, as fit and repeat make it from a
    :class:`DetectorSpec` of ``options``; ``reference_image`` and ``reference_pixels`` (N, 2) in it: a
    template kind's (``seed``: its robust sampling); ``windowed``: dots each in its own window."""
    pixels = None if reference_pixels is None else np.asarray(reference_pixels, dtype=float)
    return target_kind(kind).make(DetectorSpec(kind, n_points=n_points, template_pixels=pixels, **options), reference_image, seed, windowed)


def bias_rows(m: NDArray[np.float64], normal: ArrayLike, motion: ArrayLike, shapes: Sequence) -> NDArray[np.float64]:
    """How every frame's residuals (K, R) move with a shift of each point's (m_y, m_z), shape
    (K, R, 2N): -1 on a point's own reprojection errors, and its shapes' residuals' derivative."""
    points = 2 * m.shape[1]
    own = np.broadcast_to(-np.eye(points), (m.shape[0], points, points))
    return np.concatenate([own, _shape_bias_rows(m, normal, motion, shapes)], axis=1)


class TaughtPathTrajectory:
    """The exact desired signals of a simulated taught run (the ground truth).

    ``theta_d = phi* - phi_d``, ``x_hd = Rz(phi_d)^T (p* - p_d) / d*`` (3), (14) from the
    profile's poses (start at t = 0, F* at ``reference_pose``, d* in m); derivatives by (25).
    """

    def __init__(self, profile: CommandProfile, start_pose: ArrayLike, reference_pose: ArrayLike, d_star: float) -> None:
        self.profile = profile
        self.start_pose = np.asarray(start_pose, dtype=float)
        self.reference_pose = np.asarray(reference_pose, dtype=float)
        self.d_star = float(d_star)
        self.t_start = 0.0
        self.t_end = profile.t_end
        self._segment_starts = profile.segment_start_poses(self.start_pose)

    def pose(self, t: ArrayLike) -> NDArray[np.float64]:
        """Taught robot pose at times ``t`` (held after the end)."""
        return self.profile.poses_at(t, self.start_pose, self._segment_starts)

    def evaluate(self, t: ArrayLike) -> DesiredState:
        t = np.asarray(t, dtype=float)
        poses = self.pose(t)
        _, x_f = relative_planar_pose(poses, self.reference_pose)
        # Unwrap relative to the reference so that theta_d is continuous along the path.
        theta_d = self.reference_pose[2] - poses[..., 2]
        x_hd1 = x_f[..., 0] / self.d_star
        x_hd2 = x_f[..., 1] / self.d_star
        v, w = self.profile.commands_at(t)
        return _desired_state(theta_d, x_hd1, x_hd2, -w, -v / self.d_star + x_hd2 * w, -x_hd1 * w)


def taught_views(route: RouteWorld, times: ArrayLike, pixel_noise: float = 0.0, rng: np.random.Generator | None = None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.float64]]]:
    """What ``route``'s taught drive sees at ``times`` (s): the poses (K, 3), each target's span
    (K, T) (:meth:`~hbvs_cli.sim.route_world.RouteWorld.spans`) and each one's exact pixels (K, N_j, 2)
    plus Gaussian noise of ``pixel_noise`` px from ``rng``, NaN where it is not seen well (span below
    :data:`~hbvs_cli.sim.route_world.MIN_SPAN_PX`)."""
    poses = route.profile.poses_at(np.asarray(times, dtype=float), route.start_pose)
    spans = np.array([route.spans(pose) for pose in poses])
    pixels = []
    for index, world in enumerate(route.worlds):
        seen = np.array([world.pixels(route.local_pose(index, pose)) for pose in poses])
        if pixel_noise > 0:
            seen = seen + rng.normal(0.0, pixel_noise, seen.shape)
        seen[spans[:, index] < MIN_SPAN_PX] = np.nan
        pixels.append(seen)
    return poses, spans, pixels


def run_closed_loop(sense, trajectory, controller, start_pose: ArrayLike, dt: float, duration: float):
    """``repeat --sim``'s loop (:meth:`~hbvs_cli.sim.closed_loop.Simulation.run`) without its camera:
    ``sense(pose, t) -> Observation`` every ``dt`` (s) for ``duration`` (s), no latency, limits or filter."""
    return SimulatedRobot(sense, trajectory, start_pose, dt, duration).run(controller, ActuatorLimits())


def read_route_file(path) -> RouteFile:
    """The route of a fit file, as ``hbvs repeat`` reads it (:func:`~hbvs_cli.io.route_file.route_of`)."""
    return route_of(read_fit_file(str(path)), str(path))


def fit_route(route: RouteWorld, t: ArrayLike, pixels: Sequence[ArrayLike], spans: ArrayLike) -> RouteFit:
    """``route`` fitted as the fit stage does (stages/fit_route.py) from its taught views at the frame
    times ``t`` (F,) (s) (:func:`taught_views`: ``pixels`` one (F, N_j, 2) per target, NaN where not
    found, and their ``spans``): split into segments (:func:`~hbvs_cli.core.route.split_route`),
    each fitted as a single-target drive (:func:`~hbvs_cli.core.desired.fit_desired_trajectory`,
    Remark 1, n*_i and the uncertainty per segment, with its kind's detector errors) against F*_i at
    the frame where its target appears largest, and each transition estimated from both fits' desired
    signals over the overlap (:func:`~hbvs_cli.core.route.estimate_transitions`)."""
    t = np.asarray(t, dtype=float)
    segments = split_route(np.asarray(spans) >= MIN_SPAN_PX, spans)
    fits: list[DesiredFit] = []
    references: list[int] = []
    for segment in segments:
        frames = slice(segment.first, segment.last + 1)
        target_pixels = np.asarray(pixels[segment.target], dtype=float)[frames]
        reference = segment.first + int(np.argmax(view_spans(target_pixels)))
        errors = target_kind(route.worlds[segment.target].target.kind).errors
        fits.append(fit_desired_trajectory(t[frames], target_pixels, reference - segment.first, route.camera, None,
                                           max_lost=0.5, max_gap=5.0, warn=lambda message: None, errors=errors))
        references.append(reference)
    return RouteFit(list(segments), fits, references, estimate_transitions(t, segments, fits))
