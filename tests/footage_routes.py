"""Route footage from the independent footage maker (:mod:`footage`, issue 47): a drive of
straight legs joined by left turns, a wall panel (dots, a marker board, photographs) at the
end of each leg facing back along it, all of them drawn into each frame, the nearest last.

Like :mod:`footage`, nothing here imports ``hbvs_cli``. Written out: ``drive.avi``,
``camera.yaml`` and ``truth.npz`` (times, poses); :func:`segment_truth` gives n* and d* of
any segment's target for any reference frame, :func:`transition_truth` rho and the heading
between two segments' references.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from footage import WALL_MPP, Camera, Drive, Effects, FootageMaker, Wall, _canvas, _disc, _lighting, marker_board_wall, photo_wall, wall_homography

#: The floor and far walls behind the panels: a uniform dark gray (BGR).
BACKGROUND = (70, 70, 70)


@dataclass(frozen=True)
class RouteDrive(Drive):
    """Straight ``legs`` (m) at ``speed`` (m/s), each but the last followed by a left turn of
    ``turn_deg`` on a ``radius`` (m) circle; :func:`route_drive` makes one whose ``duration`` is theirs."""

    legs: tuple[float, ...] = (3.0, 3.0)
    turn_deg: float = 25.0
    radius: float = 3.0
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    speed: float = 0.25

    @property
    def pieces(self) -> list[tuple[float, float]]:
        """(duration s, turn rate rad/s) of each leg and turn in order."""
        turn = (np.radians(self.turn_deg) * self.radius / self.speed, self.speed / self.radius)
        out: list[tuple[float, float]] = []
        for leg in self.legs:
            out += [(leg / self.speed, 0.0), turn]
        return out[:-1]

    def v(self, t: float) -> float:
        return self.speed

    def w(self, t: float) -> float:
        ends = np.cumsum([d for d, _ in self.pieces])
        return self.pieces[min(int(np.searchsorted(ends, t, side="right")), len(ends) - 1)][1] if t >= 0 else 0.0

    def leg_ends(self) -> np.ndarray:
        """The pose (x, y, phi) at the end of each leg."""
        ends = np.cumsum([d for d, _ in self.pieces])[::2]
        return self.poses(np.concatenate([[0.0], ends]))[1:]


def route_drive(legs: tuple[float, ...], fps: float, turn_deg: float) -> RouteDrive:
    """The :class:`RouteDrive` of ``legs`` and ``turn_deg`` at ``fps``, lasting as long as its legs and turns."""
    drive = RouteDrive(legs=legs, fps=fps, turn_deg=turn_deg)
    return replace(drive, duration=float(sum(d for d, _ in drive.pieces)))


def placed(wall: Wall, end: np.ndarray, ahead: float, right: float) -> Wall:
    """``wall`` centred ``ahead`` m beyond a leg's end pose ``end`` and ``right`` m to its right, facing back along the leg."""
    c, s = np.cos(end[2]), np.sin(end[2])
    x, y = end[0] + ahead * c + right * s, end[1] + ahead * s - right * c
    return replace(wall, centre=(x, y, wall.centre[2]), yaw=float(end[2]))


class RouteMaker(FootageMaker):
    """Frames of several walls: each warped into the frame where it lies wholly in front of
    the camera, over :data:`BACKGROUND`, the farther first; ``hidden`` = (wall, t0, t1): that
    wall is not drawn in the frames from t0 to t1 (s)."""

    def __init__(self, walls: list[Wall], camera: Camera, effects: Effects = Effects(), seed: int = 0,
                 hidden: tuple[int, float, float] | None = None) -> None:
        super().__init__(walls[0], camera, effects, seed)
        self.walls = [FootageMaker(wall, camera, effects).wall for wall in walls]  # each band-limited as one wall is
        self.hidden, self._now = hidden, 0.0

    def _exposure(self, pose_of_time, t: float) -> np.ndarray:
        self._now = t
        return super()._exposure(pose_of_time, t)

    def _warp(self, pose: np.ndarray) -> np.ndarray:
        canvas = np.empty((self.canvas[1], self.canvas[0], 3), np.uint8)
        canvas[:] = BACKGROUND
        eye = np.array([pose[0], pose[1]])
        forward = np.array([np.cos(pose[2]), np.sin(pose[2])])
        order = sorted(self.walls, key=lambda wall: -np.linalg.norm(np.asarray(wall.centre[:2]) - eye))
        if self.hidden is not None and self.hidden[1] <= self._now < self.hidden[2]:  # as if someone stood in front of it
            order = [wall for wall in order if wall is not self.walls[self.hidden[0]]]
        for wall in order:
            h, w = wall.image.shape[:2]
            corners = (wall.wall_to_world() @ np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], float).T).T
            if np.min((corners[:, :2] - eye) @ forward) < 0.2:  # (partly) behind the camera: a homography would fold it
                continue
            H = wall_homography(wall, self.camera, pose, self.K_canvas)
            warped = cv2.warpPerspective(wall.image, H, self.canvas, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            inside = cv2.warpPerspective(np.full((h, w), 255, np.uint8), H, self.canvas, flags=cv2.INTER_NEAREST) > 0
            canvas[inside] = warped[inside]
        return canvas


def dot_poster(scale: float = 1.0, centre_height: float = 1.0) -> Wall:
    """Four black dots of 7 cm radius, not in a rectangle, on a light 2.0 x 1.2 m poster (a panel
    of its own), all of it ``scale`` times as large, its centre ``centre_height`` m above the floor."""
    width, height = 2.0 * scale, 1.2 * scale
    image = _canvas(width, height, (200, 205, 210))
    points = [_disc(image, (scale * u, scale * v), 0.07 * scale, (30, 30, 30), height)
              for u, v in ((0.3, 0.9), (1.6, 0.95), (1.7, 0.3), (0.45, 0.25))]
    return Wall(_lighting(image, 0.9, 1.05), WALL_MPP, (0.0, 0.0, centre_height), yaw=0.0, points=np.array(points))


#: The short route: two legs of 3 m with a left turn of 40 deg between them; the dot poster 5 m
#: beyond the first leg's end and 1.2 m to its left, the marker board 3 m beyond the second's and
#: 0.6 m to its left: the board comes into view during the turn, while the dots are still seen.
SHORT_ROUTE = {"legs": (3.0, 3.0), "turn_deg": 40.0, "places": ((5.0, -1.2), (3.0, -0.6))}
#: The long route (20.7 m, 414 frames at 5 fps): four legs of 4 m joined by left turns of 30 deg;
#: the dot poster 5 m beyond the first leg's end, the board and the two photographs 3 m beyond
#: theirs and 0.4 m to the right. Each target is seen from afar during the leg before its own
#: (the photographs first about 9 m off), none hidden behind another's panel while it is followed.
LONG_ROUTE = {"legs": (4.0, 4.0, 4.0, 4.0), "turn_deg": 30.0, "places": ((5.0, 0.0), (3.0, 0.4), (3.0, 0.4), (3.0, 0.4))}


def route_walls(drive: RouteDrive, places: tuple[tuple[float, float], ...]) -> list[Wall]:
    """The first ``len(places)`` of: a :func:`dot_poster`, a 3x2 board of 30 cm markers, two photographs
    (coffee, astronaut), each placed (:func:`placed`) at ``(ahead, right)`` of its leg's end."""
    walls = [dot_poster(), marker_board_wall(side_m=0.3, gap_m=0.06), photo_wall("coffee", 1.4), photo_wall("astronaut", 1.4)]
    return [placed(wall, end, ahead, right) for wall, end, (ahead, right) in zip(walls, drive.leg_ends(), places)]


def make_route_footage(folder: Path, legs: tuple[float, ...], turn_deg: float, places: tuple[tuple[float, float], ...],
                       fps: float = 5.0, seed: int = 7, hidden: tuple[int, float, float] | None = None) -> dict:
    """Render the :func:`route_drive` of ``legs`` and ``turn_deg`` at ``fps``, past one wall per
    leg placed at ``places`` (``hidden``: see :class:`RouteMaker`), into ``folder``; its files
    and truth, and ``walls`` (in order)."""
    drive = route_drive(legs, fps, turn_deg)
    walls = route_walls(drive, places)
    maker = RouteMaker(walls, Camera(), Effects(), seed=seed, hidden=hidden)
    return {**maker.write(Path(folder), drive), "walls": walls}


def make_depth_route_footage(folder: Path, fps: float = 5.0, seed: int = 7) -> dict:
    """Two consecutive targets at very different depths: 2.5 m straight past a marker board far
    ahead on the right, then a left turn of 25 deg that takes it out of the view about 6 m from
    its plane, and 1 m toward a small dot poster (0.8 m wide, 0.4 m up) that the drive ends 1.5 m
    from (its dots too small to follow until about 4 m off). Written as :func:`make_route_footage`."""
    drive = replace(RouteDrive(legs=(2.5, 1.0), fps=fps, turn_deg=25.0), duration=0.0)
    drive = replace(drive, duration=float(sum(d for d, _ in drive.pieces)))
    first, last = drive.leg_ends()
    walls = [placed(marker_board_wall(side_m=0.36, gap_m=0.07), first, 6.0, 3.0), placed(dot_poster(0.4, 0.4), last, 1.5, 0.0)]
    maker = RouteMaker(walls, Camera(), Effects(), seed=seed)
    return {**maker.write(Path(folder), drive), "walls": walls}


def segment_truth(made: dict, target: int, reference: int) -> dict:
    """theta_d, x_hd, n* and d* of wall ``target`` with F* at frame ``reference`` (:meth:`FootageMaker.truth`)."""
    return FootageMaker(made["walls"][target], Camera()).truth(made["t"], made["poses"], reference)


def transition_truth(made: dict, targets: tuple[int, int], references: tuple[int, int]) -> tuple[float, float]:
    """rho = d*_2 / d*_1 and the heading (rad) of F*_2 seen from F*_1 for two segments' targets and reference frames."""
    first, second = (segment_truth(made, t, r) for t, r in zip(targets, references))
    poses = made["poses"]
    return second["d_star"] / first["d_star"], float(poses[references[1], 2] - poses[references[0], 2])
