"""Fit files written before the typed hand-off (by 7bf9143's code, in tests/data) still read,
into typed values, and are written again to the same bytes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hbvs_cli.core.depth import DepthEstimate
from hbvs_cli.core.desired import FrameStats, PixelResidual, UncertaintySummary
from hbvs_cli.core.fit_model import DepthEstimates, DetectorSpec, SensorSettings
from hbvs_cli.core.gains import GainSuggestion
from hbvs_cli.core.trajectory import FeedforwardCondition
from hbvs_cli.io.fit_file import model_from_message, model_message, read_fit_file
from hbvs_cli.io.mcap import encode_json

DATA = Path(__file__).parent / "data"


def _stored_model_message(path: Path) -> dict:
    from mcap.reader import make_reader

    with open(path, "rb") as stream:
        (_, _, message), = make_reader(stream).iter_messages(topics=["/fit/model"])
    return json.loads(message.data)


def _written_again(message: dict) -> bytes:
    """The message as the current code writes the model it reads from it (same stamp)."""
    model = model_from_message(message, "old")
    again = model_message(model, 0)
    again["timestamp"] = message["timestamp"]
    again["hbvs_version"] = message["hbvs_version"]
    return encode_json(again)


def test_a_fit_file_written_before_reads_into_typed_values_and_writes_the_same_bytes():
    path = DATA / "fit_7bf9143.mcap"
    model = read_fit_file(path).model
    stored = _stored_model_message(path)
    assert isinstance(model.frames, FrameStats) and isinstance(model.residual_px, PixelResidual)
    assert isinstance(model.condition35, FeedforwardCondition) and isinstance(model.uncertainty, UncertaintySummary)
    assert isinstance(model.gains, GainSuggestion) and isinstance(model.render, SensorSettings)
    assert isinstance(model.detector, DetectorSpec) and isinstance(model.depth, DepthEstimates)
    assert isinstance(model.depth.commands, DepthEstimate) and model.depth.target_size is None
    # The numbers as the old file recorded them, now attributes.
    assert (model.frames.used, model.frames.total, model.frames.truncated_input) == (stored["frames"]["used"], stored["frames"]["total"], False)
    assert model.residual_px.rms == stored["residual_px"]["rms"] and model.residual_px.max == stored["residual_px"]["max"]
    assert model.depth.commands.dhat0 == stored["depth"]["commands"]["dhat0"]
    assert model.gains.gains.k_2 == stored["gains"]["k_2"] and model.suggested_gains() == model.gains.gains
    assert model.uncertainty.theta_d_sigma_deg.max == stored["uncertainty"]["theta_d_sigma_deg"]["max"]
    assert np.array_equal(model.detector.initial_pixels, np.asarray(stored["detector"]["initial_pixels"]))
    assert model.taught_frame_interval() == pytest.approx(0.25)
    assert _written_again(stored) == encode_json(stored)


@pytest.mark.parametrize("kind", ["chessboard", "charuco"])
def test_board_fit_models_written_before_read_and_write_the_same_bytes(kind):
    stored = json.loads((DATA / f"fit_model_{kind}_7bf9143.json").read_text())
    model = model_from_message(stored, kind)
    assert model.detector.kind == kind and model.detector.board == tuple(stored["detector"]["board"])
    assert model.depth == DepthEstimates()  # footage without commands or a size: no estimate
    assert model.frames.frame_interval_s == pytest.approx(0.2)
    assert _written_again(stored) == encode_json(stored)


def test_a_fit_file_whose_calibration_was_assumed_still_reads_and_writes_the_same_bytes():
    """Fit files of issue 46's first version recorded a calibration without deviations as
    "assumed" (0.2 % of f counted in the band); today's fit says "unstated" (not counted), and
    the old word reads as it was written."""
    stored = _stored_model_message(DATA / "fit_7bf9143.mcap")
    stored["uncertainty"] |= {"calibration_normal_sigma_deg": 12.6, "calibration": "assumed"}
    model = model_from_message(stored, "old")
    assert (model.uncertainty.calibration, model.uncertainty.calibration_normal_sigma_deg) == ("assumed", 12.6)
    assert _written_again(stored) == encode_json(stored)


@pytest.mark.parametrize("field, value, words", [
    ("board", [2], "detector board must be two small whole numbers"),
    ("marker_ids", ["a"], "detector marker_ids must be a list of small whole numbers"),
    ("n_points", True, "detector n_points must be a small whole number"),
    ("template_pixels", [[1, 2, 3]], "detector template_pixels must be rows of (u, v) pixels"),
    ("initial_pixels", [[1, 2]], "initial_pixels has 1 points, the reference 35"),
    ("kind", "dots", "detector kind 'dots' differs from the target kind 'chessboard'"),
])
def test_a_malformed_detector_record_is_one_clear_error(field, value, words):
    from hbvs_cli.errors import RecordingError

    message = json.loads((DATA / "fit_model_chessboard_7bf9143.json").read_text())
    message["detector"][field] = value
    with pytest.raises(RecordingError, match="the fit model is malformed") as caught:
        model_from_message(message, "hostile.mcap")
    assert words in str(caught.value)
