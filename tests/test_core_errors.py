"""The core raises domain errors; the CLI alone turns them into the exit codes users know."""

from __future__ import annotations

import ast
import subprocess
import sys

import numpy as np
import pytest

from conftest import REPO
from hbvs_cli import errors
from hbvs_cli.core.camera import DEFAULT_CAMERA
from hbvs_cli.core.controller import AdaptiveTrackingController, ControllerGains
from hbvs_cli.core.desired import fit_desired_trajectory
from hbvs_cli.core.path import CommandProfile
from hbvs_cli.core.trajectory import SplineTrajectory


def _raised_names(path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and isinstance(node.exc.func, ast.Name):
            names.add(node.exc.func.id)
    return names


def test_core_raises_only_domain_errors():
    raised = set().union(*(_raised_names(path) for path in (REPO / "hbvs_cli" / "core").glob("*.py")))
    ours = {name for name in raised if isinstance(getattr(errors, name, None), type)}
    assert ours, "the scan found no error of ours"
    # CalibrationError: the camera's intrinsics are checked as a calibration file is.
    not_domain = {name for name in ours if not issubclass(getattr(errors, name), errors.DomainError)} - {"CalibrationError"}
    assert not_domain == set()
    assert "UsageError" not in raised and "InputError" not in raised


@pytest.mark.parametrize("error, code", [
    (errors.InvalidValueError("x"), 2), (errors.MalformedDataError("x"), 3), (errors.InsufficientDataError("x"), 3),
    (errors.NoValidBranchError("x"), 4), (errors.UsageError("x"), 2), (errors.RecordingError("x"), 3),
    (errors.TargetLostError("x"), 5), (errors.OutputError("x"), 6),
])
def test_the_cli_maps_each_kind_to_its_exit_code(error, code):
    assert isinstance(error, errors.HbvsError)
    assert error.exit_code == code


def test_domain_errors_from_the_core():
    with pytest.raises(errors.InvalidValueError, match="the initial depth estimate dhat0 must be a positive depth in metres, got 0.0"):
        AdaptiveTrackingController(ControllerGains(), dhat0=0.0)
    with pytest.raises(errors.MalformedDataError, match="command times must increase strictly"):
        CommandProfile(t=np.array([0.0, 0.0]), v=np.zeros(2), w=np.zeros(2), t_end=1.0)
    with pytest.raises(errors.MalformedDataError, match="malformed trajectory model"):
        SplineTrajectory.from_dict({})
    pixels = np.full((8, 3, 2), np.nan)
    with pytest.raises(errors.InsufficientDataError, match="not found in any frame") as info:
        fit_desired_trajectory(np.arange(8) / 30, pixels, 0, DEFAULT_CAMERA, None, max_lost=0.3, max_gap=1.0)
    assert info.value.facts == {"reason": "not_found"}


@pytest.mark.parametrize("arguments, code, message", [
    (["teach", "--dots", "11"], 2, "hbvs: error: a dot target has 3 to 10 dots, got 11"),
    (["repeat", "{fit}", "--sim", "--dhat0", "-1"], 2,
     "hbvs: error: Invalid value for '--dhat0': Input should be greater than or equal to 0.001 (see 'hbvs repeat -h')"),
])
def test_users_see_the_same_exit_code_and_line(tmp_path, default_fit, arguments, code, message):
    arguments = [a.format(fit=default_fit[0]) for a in arguments] + ["-o", str(tmp_path / "out.mcap")]
    result = subprocess.run([sys.executable, "-m", "hbvs_cli", *arguments], capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == code
    assert result.stderr.strip().splitlines()[-1] == message
    assert not (tmp_path / "out.mcap").exists()


def test_fit_words_too_little_data_as_before():
    """core/desired.py says what is missing; stages/fit.py says it in the options' words, the
    messages users saw when the algorithm lived in the stage."""
    from hbvs_cli.core.desired import frame_stats
    from hbvs_cli.stages.fit import FitOptions, _insufficient_data_message

    options = FitOptions(input="teach.mcap", max_lost=0.3, max_gap=1.0)
    t = np.arange(100) / 10.0
    index = np.arange(100)
    cases = []
    for used in (index < 4, index % 2 == 0, (index < 30) | (index >= 47)):
        with pytest.raises(errors.InsufficientDataError) as info:
            frame_stats(t, used, 0, options.max_lost, options.max_gap)
        cases.append(_insufficient_data_message(info.value, options))
    assert cases == [
        "the target was found in only 4 of 100 frames; at least 5 are needed",
        "the target is missing from 50 % of the frames (more than --max-lost 30 %)",
        "the target is missing from t = 2.90 s to 4.70 s (1.80 s), longer than --max-gap 1 s can bridge",
    ]
    pixels = np.full((8, 3, 2), 100.0)
    pixels[2] = np.nan
    with pytest.raises(errors.InsufficientDataError) as info:
        fit_desired_trajectory(np.arange(8) / 10.0, pixels, 2, DEFAULT_CAMERA, None, max_lost=0.3, max_gap=1.0)
    assert _insufficient_data_message(info.value, options) == (
        "the target was not found in the reference frame 2 (t = 0.20 s); choose another with --reference")
