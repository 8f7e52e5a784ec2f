"""The target-kind registry (hbvs_cli/perception/target_kinds.py): a kind registered from
outside the package is fitted and replayed end to end, with no file of hbvs_cli touched."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import footage
from conftest import call_hbvs
from hbvs_cli.core.desired import DetectorErrors
from hbvs_cli.core.fit_model import DetectorSpec
from hbvs_cli.core.plane import UNIT_SQUARE
from hbvs_cli.io.fit_file import read_fit_file
from hbvs_cli.io.run_file import read_run
from hbvs_cli.report.build import build_report
from hbvs_cli.perception import TARGET_KINDS, Detection, TargetKind, register_target_kind

SQUARE_SIDE_M = 0.8


class BrightSquareDetector:
    """The four corners (TL, TR, BR, BL) of the largest bright quadrilateral in a frame: its
    outline's polygon, each corner refined to the sub-pixel (``cv2.cornerSubPix``)."""

    kind, n_points = "square", 4

    def detect(self, image: np.ndarray, prediction: np.ndarray | None = None) -> Detection:
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        _, mask = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        lost = Detection(np.full((4, 2), np.nan), False, len(contours), 0)
        if not contours:
            return lost
        outline = max(contours, key=cv2.contourArea)
        quad = cv2.approxPolyDP(outline, 0.02 * cv2.arcLength(outline, True), True).astype(np.float32)
        if len(quad) != 4 or cv2.contourArea(outline) < 400:
            return lost
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)
        corners = cv2.cornerSubPix(gray, quad, (4, 4), (-1, -1), criteria).reshape(-1, 2).astype(float)
        by_sum, by_diff = corners.sum(axis=1), corners[:, 0] - corners[:, 1]
        ordered = corners[[np.argmin(by_sum), np.argmax(by_diff), np.argmax(by_sum), np.argmin(by_diff)]]
        return Detection(ordered, True, len(contours), 0)

    def reset(self) -> None:
        pass


@pytest.fixture
def square_kind():
    """The toy kind, registered for one test (and taken out again)."""
    register_target_kind(TargetKind(
        name="square", spec=lambda request: DetectorSpec(kind="square", n_points=4),
        make=lambda spec, template, seed, windowed: BrightSquareDetector(),
        errors=DetectorErrors("square", bias_fraction=0.5, correlated=False, expected_precision=(0.35, 5e-3)),
        precision_scale=17.7, shapes=lambda spec: [(range(4), UNIT_SQUARE)], size_pair=lambda spec, m_ref, normal: ((0, 1), 1.0),  # --target-size: its side
    ))
    yield
    del TARGET_KINDS["square"]


def _square_wall() -> footage.Wall:
    """A plain white square, SQUARE_SIDE_M wide, on a dark grey wall."""
    image = footage._canvas(3.0, 2.0, (70, 70, 70))
    side = int(round(SQUARE_SIDE_M / footage.WALL_MPP))
    row0, col0 = (image.shape[0] - side) // 2, (image.shape[1] - side) // 2
    image[row0:row0 + side, col0:col0 + side] = 235
    corners = np.array([[col0, row0], [col0 + side, row0], [col0 + side, row0 + side], [col0, row0 + side]], float) - 0.5
    return footage.Wall(image, footage.WALL_MPP, (5.0, 0.0, 1.0), yaw=np.radians(-5.0), points=corners)


def test_a_target_kind_registered_from_outside_the_package_is_fitted_and_replayed(square_kind, tmp_path):
    """`fit --target square` on footage of a white square: the fit follows the truth, d* from
    --target-size is the square's distance, and `repeat --replay` detects it again."""
    drive = footage.Drive(duration=10.0, fps=3.0)
    made = footage.FootageMaker(_square_wall(), footage.Camera(), footage.Effects(), seed=3).write(tmp_path / "square", drive)
    teach, fit, run = tmp_path / "teach.mcap", tmp_path / "fit.mcap", tmp_path / "run.mcap"
    result = call_hbvs("teach", "--video", str(made["video"]), "--calibration", str(made["calibration"]), "-o", str(teach), "-q")
    assert result.returncode == 0, result.stderr.decode()
    result = call_hbvs("fit", str(teach), "--target", "square", "--target-size", str(SQUARE_SIDE_M), "-o", str(fit))
    assert result.returncode == 0, result.stderr.decode()
    model = read_fit_file(fit).model
    assert model.target_kind == model.detector.kind == "square" and model.frames.used == model.frames.total == 30
    errors = footage.errors_against_truth(model, made)
    print(f"\nsquare: {errors}, dhat0 {model.dhat0:.3f} m, d* {made['d_star']:.3f} m, residual {model.residual_px.rms:.3f} px")
    # Measured (seed 3): theta_d 0.10 deg, x_hd1 3.0e-4, n* 0.03 deg RMS off; d* 5.010 m for 4.994 m.
    assert errors["theta_deg"] < 0.2 and errors["x_hd1"] < 1e-3 and errors["normal_deg"] < 0.2
    assert model.dhat0_source == "target-size" and model.dhat0 == pytest.approx(made["d_star"], rel=0.01)
    result = call_hbvs("repeat", str(fit), "--replay", str(teach), "-o", str(run), "-q")
    assert result.returncode == 0, result.stderr.decode()
    assert build_report(read_run(run)).target.lost_frames == 0  # the replay's detector is the registered one
    # Its fit file, read where the kind is not registered: one line saying so, no run file.
    square = TARGET_KINDS.pop("square")
    result = call_hbvs("repeat", str(fit), "--replay", str(teach), "-o", str(tmp_path / "no-run.mcap"))
    register_target_kind(square)
    lines = result.stderr.decode().strip().splitlines()
    assert result.returncode == 3 and len(lines) == 1 and "target kind 'square' is none this hbvs knows" in lines[0], lines
    assert not (tmp_path / "no-run.mcap").exists()
    # A kind nobody registered: one line naming the registered ones.
    result = call_hbvs("fit", str(teach), "--target", "circle", "-o", str(tmp_path / "no.mcap"))
    assert result.returncode == 2 and "square" in result.stderr.decode() and not (tmp_path / "no.mcap").exists()
