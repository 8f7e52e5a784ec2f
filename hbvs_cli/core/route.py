"""A route longer than one view: its segments, and the transition from one to the next (issue 47).

Segment i is driven by the paper's controller against its own reference F*_i and planar target
(n*_i, d*_i). A target that leaves the view ends its segment; the next segment's target was
already in view then, so there is an overlap of frames in which both homographies are measured.
In such a frame the camera F sees F*_i and F*_{i+1} through (3), (14):
``x_f,i = d*_i x_h,i`` and ``x_f,i+1 = d*_{i+1} x_h,i+1`` (the origins of F*_i and F*_{i+1} in F),
``R_i = Rz(theta_i)``, ``R_{i+1} = Rz(theta_{i+1})``. Then F*_{i+1} seen from F*_i is

* its heading ``theta_{i+1} - theta_i`` (R_i^T R_{i+1}), the same in every overlap frame;
* its origin ``t = R_i^T (x_f,i+1 - x_f,i)``, so with ``u = t / d*_i`` and
  ``rho = d*_{i+1} / d*_i``: ``R_i u - rho x_h,i+1 = -x_h,i``, two equations per frame, linear
  in ``(u_1, u_2, rho)``: least squares over the overlap, which needs the camera to move during it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import MalformedDataError
from .bundle import correlation_inflation
from .desired import DesiredFit
from .frames import wrap_angle


@dataclass(frozen=True)
class Segment:
    """One segment of a route: ``target`` (its index in the route), its frames
    ``first``..``last`` (inclusive indices of the drive) and, from the second segment on,
    ``overlap_last``, the previous segment's last frame: frames ``first``..``overlap_last`` see
    both its target and the previous one."""

    target: int
    first: int
    last: int
    overlap_last: int | None = None


def split_route(visible: ArrayLike, sizes: ArrayLike | None = None) -> list[Segment]:
    """The segments of a drive from what each frame sees: ``visible`` (K frames, T targets)
    bool, each target seen well enough; ``sizes`` (K, T), how large each appears (e.g. the
    span of its points, px). The first segment follows a target seen in frame 0; each segment
    ends when its target leaves the view; the next follows, of the targets seen in that last
    frame and not yet followed, the largest there (without ``sizes``: the one that stays longest
    in view), from where its present stretch of visibility began. MalformedDataError when the
    first frame sees no target or one leaves with no other in view (the route has a gap)."""
    visible = np.asarray(visible, dtype=bool)
    if visible.ndim != 2 or visible.shape[0] == 0:
        raise MalformedDataError("the visibility of a route is a (frames, targets) table")
    frames = visible.shape[0]
    segments: list[Segment] = []
    frame, followed = 0, set()
    while True:
        candidates = [int(t) for t in np.flatnonzero(visible[frame]) if t not in followed]
        if not candidates:
            where = "the first frame" if not segments else f"frame {frame}"
            raise MalformedDataError(f"{where} sees no target to follow: the route has a gap")
        ends = {t: _run(visible[:, t], frame)[1] for t in candidates}
        rank = ends if sizes is None else {t: float(np.asarray(sizes)[frame, t]) for t in candidates}
        target = max(candidates, key=lambda t: (rank[t], -t))
        start = max(_run(visible[:, target], frame)[0], segments[-1].first + 1) if segments else 0
        segments.append(Segment(target, start, ends[target], overlap_last=frame if segments else None))
        followed.add(target)
        if ends[target] == frames - 1:
            return segments
        frame = ends[target]


def _run(column: NDArray[np.bool_], frame: int) -> tuple[int, int]:
    """The first and last frames of the stretch of True in ``column`` that holds ``frame``."""
    before = np.flatnonzero(~column[: frame + 1])
    after = np.flatnonzero(~column[frame:])
    return (int(before[-1]) + 1 if before.size else 0), (frame + int(after[0]) - 1 if after.size else column.size - 1)


def bridge_brief_gaps(visible: NDArray[np.bool_], t: NDArray[np.float64], max_gap: float) -> NDArray[np.bool_]:
    """``visible`` (F, N: whether each of N targets is followable in each of F frames, at times ``t`` (F,), s) with
    each target's gaps between two sightings at most ``max_gap`` s apart (``--max-gap``, the gaps a segment's spline
    bridges) filled when it is then seen again for at least half that long: a target hidden a moment (someone walking
    past) does not end its segment there, one flickering as it leaves the view does not stay."""
    filled = np.array(visible, bool)
    for column in filled.T:  # views: filling a column fills ``filled``
        seen = np.flatnonzero(column)
        for before, after in zip(seen[:-1], seen[1:]):
            if after > before + 1 and t[after] - t[before] <= max_gap and t[_run(column, after)[1]] - t[after] >= max_gap / 2:
                column[before:after] = True
    return filled


@dataclass(frozen=True)
class Transition:
    """F*_{i+1} relative to F*_i, estimated over an overlap: ``depth_ratio`` rho = d*_{i+1}/d*_i,
    ``heading`` (rad) of F*_{i+1} in F*_i, ``origin_over_depth`` (2,) its origin in F*_i divided
    by d*_i (paper axes: x forward, y left), each with its standard deviation (``covariance``
    (3, 3) of (u_1, u_2, rho)); ``frames`` used; ``residual_rms`` of the fit's equations."""

    depth_ratio: float
    depth_ratio_std: float
    heading: float
    heading_std: float
    origin_over_depth: NDArray[np.float64]
    covariance: NDArray[np.float64]
    frames: int
    residual_rms: float

    def carried_depth(self, dhat: float) -> float:
        """The adaptive estimate (31) of d*_i carried over to segment i+1 (m): rho dhat."""
        return self.depth_ratio * float(dhat)

    def in_next(self, theta: float, x_h: ArrayLike) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
        """``theta`` (rad) and ``x_h`` (2,) of F against F*_i, (4), (14), expressed against
        F*_{i+1}: ``theta + heading`` and ``(x_h + Rz(theta) u) / rho`` (module docstring),
        with ``d x_h' / d theta = Rz'(theta) u / rho``, the lever of F*_{i+1}'s origin."""
        c, s = np.cos(theta), np.sin(theta)
        u1, u2 = self.origin_over_depth
        rho = self.depth_ratio
        x_next = (np.asarray(x_h, dtype=float) + (c * u1 - s * u2, s * u1 + c * u2)) / rho
        return float(theta + self.heading), x_next, np.array((-s * u1 - c * u2, c * u1 - s * u2)) / rho

    def carried_state(self, state: ArrayLike, covariance: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """A state filter's ``state`` (theta, x_h1, x_h2, 1/d*_i) and its ``covariance`` (4, 4)
        against F*_i, carried to F*_{i+1} (:meth:`in_next`, 1/d*_{i+1} = 1/(rho d*_i)): the
        covariance through the Jacobian, plus the transition's own (rho, u and heading)."""
        state = np.asarray(state, dtype=float)
        theta, x_next, lever = self.in_next(state[0], state[1:3])
        rho = self.depth_ratio
        carried = np.array((theta, *x_next, state[3] / rho))
        jacobian = np.diag((1.0, 1.0 / rho, 1.0 / rho, 1.0 / rho))
        jacobian[1:3, 0] = lever
        c, s = np.cos(state[0]), np.sin(state[0])
        by_transition = np.zeros((4, 3))  # d carried / d (u_1, u_2, rho)
        by_transition[1:3, :2] = np.array(((c, -s), (s, c))) / rho
        by_transition[1:, 2] = -carried[1:] / rho
        spread = jacobian @ np.asarray(covariance, dtype=float) @ jacobian.T + by_transition @ self.covariance @ by_transition.T
        spread[0, 0] += self.heading_std**2
        return carried, spread


def estimate_transition(theta_i: ArrayLike, x_h_i: ArrayLike, theta_next: ArrayLike, x_h_next: ArrayLike,
                        modes_i: ArrayLike | None = None, modes_next: ArrayLike | None = None) -> Transition:
    """The transition from segment i to i+1 from the same overlap frames seen through both
    homographies: ``theta_*`` (K,) rad and ``x_h_*`` (K, 2), (14), of F relative to F*_i and to
    F*_{i+1}. Least squares on ``R_i u - rho x_h,i+1 = -x_h,i``; the covariance is the residuals'
    long-run variance (:func:`~.bundle.correlation_inflation`: they are smoothed signals') times
    (A^T A)^-1, the heading's its scatter's; plus, with ``modes_*`` (K, 3, C), each fit's stated
    errors (:attr:`.FitUncertainty.error_modes`: n*_i's and the biases', common to the
    frames, which the scatter cannot show, and the frames' own), carried through the same least
    squares and the heading's mean (the linearised (13), (14)). MalformedDataError for
    fewer than 2 frames or an overlap without the motion that separates rho from u."""
    theta_i, theta_next = np.asarray(theta_i, dtype=float).ravel(), np.asarray(theta_next, dtype=float).ravel()
    x_h_i, x_h_next = np.asarray(x_h_i, dtype=float).reshape(-1, 2), np.asarray(x_h_next, dtype=float).reshape(-1, 2)
    count = theta_i.size
    if count < 2 or not (theta_next.size == count == x_h_i.shape[0] == x_h_next.shape[0]):
        raise MalformedDataError("a transition needs at least 2 overlap frames, each seen through both homographies")
    c, s = np.cos(theta_i), np.sin(theta_i)
    design = np.zeros((2 * count, 3))
    design[0::2, 0], design[0::2, 1], design[0::2, 2] = c, -s, -x_h_next[:, 0]
    design[1::2, 0], design[1::2, 1], design[1::2, 2] = s, c, -x_h_next[:, 1]
    rhs = -x_h_i.ravel()
    normal = design.T @ design
    if np.linalg.cond(normal) > 1e12:
        raise MalformedDataError("the camera did not move during the overlap: the depth ratio cannot be told from it")
    solution = np.linalg.solve(normal, design.T @ rhs)
    residual = design @ solution - rhs
    dof = max(2 * count - 3, 1)
    covariance = float(residual @ residual) / dof * np.linalg.inv(normal) * correlation_inflation(residual.reshape(-1, 2))
    headings = wrap_angle(theta_next - theta_i)
    heading = float(np.arctan2(np.mean(np.sin(headings)), np.mean(np.cos(headings))))
    spread = np.asarray(wrap_angle(headings - heading), dtype=float)
    heading_variance = np.var(spread, ddof=1) / count * correlation_inflation(spread[:, None])
    lever = np.column_stack([-s * solution[0] - c * solution[1], c * solution[0] - s * solution[1]])  # d(R_i u)/d theta_i
    for modes, here in ((modes_i, True), (modes_next, False)):
        if modes is not None:  # each error moves the equations' sides by -dx_h,i - lever dtheta_i, or by rho dx_h,i+1
            modes = np.asarray(modes, dtype=float)
            moved = -(modes[:, 1:] + lever[:, :, None] * modes[:, :1]) if here else solution[2] * modes[:, 1:]
            carried = np.linalg.solve(normal, design.T @ moved.reshape(2 * count, -1))  # (3, C)
            covariance = covariance + carried @ carried.T
            heading_variance = heading_variance + float(np.sum(np.mean(modes[:, 0], axis=0) ** 2))
    return Transition(
        depth_ratio=float(solution[2]), depth_ratio_std=float(np.sqrt(covariance[2, 2])),
        heading=heading, heading_std=float(np.sqrt(heading_variance)),
        origin_over_depth=solution[:2], covariance=covariance, frames=count,
        residual_rms=float(np.sqrt(np.mean(residual**2))),
    )


@dataclass(frozen=True)
class RouteFit:
    """A route's fit: its ``segments``, each one's single-target fit (``fits[i]``, against
    F*_i at frame ``references[i]`` of the drive) and the ``transitions`` from each to the next."""

    segments: list[Segment]
    fits: list[DesiredFit]
    references: list[int]
    transitions: list[Transition]


def estimate_transitions(t: ArrayLike, segments: Sequence[Segment], fits: Sequence[DesiredFit]) -> list[Transition]:
    """Each transition of a route from its segments' fits (their desired trajectories'
    ``evaluate(t)``, Remark 1's splines) over each overlap of the drive's frame times ``t`` (s):
    the smoothed signals, not each frame's, since rho multiplies x_h,i+1 and noise in a regressor
    pulls its coefficient toward zero (errors in variables); with each fit's stated errors
    (:attr:`.FitUncertainty.error_modes`, where it has them) carried into the transitions' covariance."""
    t = np.asarray(t, dtype=float)
    transitions = []
    for here_fit, segment, there_fit in zip(fits, segments[1:], fits[1:]):
        shared = t[segment.first:segment.overlap_last + 1]
        here, there = here_fit.trajectory.evaluate(shared), there_fit.trajectory.evaluate(shared)
        modes = [None if fit.uncertainty is None or fit.uncertainty.error_modes is None else fit.uncertainty.error_modes(shared)
                 for fit in (here_fit, there_fit)]
        transitions.append(estimate_transition(here.theta_d, np.column_stack([here.x_hd1, here.x_hd2]),
                                               there.theta_d, np.column_stack([there.x_hd1, there.x_hd2]), *modes))
    return transitions


def view_spans(pixels: ArrayLike, least: int | None = None) -> NDArray[np.float64]:
    """The largest distance (px) between two of a target's points found in each frame (F, N, 2) where at least
    ``least`` (None: all N) were found; -1 elsewhere."""
    pixels = np.asarray(pixels, dtype=float)
    distances = np.linalg.norm(pixels[:, :, None, :] - pixels[:, None, :, :], axis=-1)
    spans = np.where(np.isfinite(distances), distances, -1.0).max(axis=(1, 2))
    found = np.all(np.isfinite(pixels), axis=2).sum(axis=1)
    return np.where(found >= (pixels.shape[1] if least is None else least), spans, -1.0)
