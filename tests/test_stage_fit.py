"""``hbvs fit``: desired signals against the truth, gaps, condition (35), bad input."""

from __future__ import annotations

import numpy as np
import pytest

from hbvs_cli.io.fit_file import read_fit_file
from oracles import target_size

from conftest import (
    SAMPLES,
    call_hbvs,
    errors_against_drive,
    fit_errors,
    gray_footage_teach,
    make_fit,
    make_teach,
    run_hbvs,
)
from oracles import copy_message

#: Measured on the default scenario (3 dots, 4 m, 640x480, f = 500 px, frames stored as
#: JPEG 90): theta_d 0.012 deg, x_hd1 2.4e-5, x_hd2 2.1e-4 RMS; x_hd1_dot within 0.15 %
#: (lossless PNG: 0.0057 deg, 1.8e-5, 4.1e-5, 0.17 %);
#: d* from the taught commands within 0.001 %. Bounds: the issue's aims.
DOTS_BOUNDS = {"theta_deg": 0.05, "x_hd1": 1e-3, "x_hd2": 1e-3, "x_hd1_dot_rel": 0.02}


def test_dots_fit_agrees_with_the_truth(default_fit, capsys):
    _, model = default_fit
    errors = fit_errors(model)
    with capsys.disabled():
        print(f"\nfit (dots, default scenario): {errors}")
    for key, bound in DOTS_BOUNDS.items():
        assert errors[key] < bound, (key, errors[key])
    # d* from the taught commands, (25): within 2 %.
    assert model.dhat0_source == "commands"
    assert abs(model.dhat0 - errors["d_star"]) < 0.02 * errors["d_star"]
    # The plane normal of a vertical wall facing F*.
    assert np.degrees(np.arccos(min(1.0, abs(model.normal @ [1.0, 0.0, 0.0])))) < 0.5
    assert model.frames.used == 600 and model.frames.lost == 0


#: Measured (the default path): ArUco theta 0.120 deg (0.113 with one pass of the corners'
#: edge refinement, 0.128 before its square joined n*'s estimate), x_hd 4.5e-4 / 2.0e-3; texture theta
#: 0.010 deg, x_hd 3.6e-5 / 8.0e-5 (0.014 deg, 3.1e-5 / 1.8e-4 before its alignment modelled
#: vignetting and matched the template's resolution). A 0.6 m marker 4 m away is less well conditioned than
#: the 2 m dot poster (yaw and lateral shift look alike: sensitivity ~ (distance / width)^2).
@pytest.mark.parametrize("kind, bounds", [
    ("aruco", {"theta_deg": 0.15, "x_hd1": 1e-3, "x_hd2": 2.5e-3, "x_hd1_dot_rel": 0.02}),
    ("texture", {"theta_deg": 0.06, "x_hd1": 1e-3, "x_hd2": 1e-3, "x_hd1_dot_rel": 0.02}),
])
def test_other_targets_agree_with_the_truth(tmp_path, kind, bounds, capsys):
    teach = make_teach(tmp_path / "teach.mcap", target=kind)
    make_fit(teach, tmp_path / "fit.mcap")
    model = read_fit_file(tmp_path / "fit.mcap").model
    errors = fit_errors(model)
    with capsys.disabled():
        print(f"\nfit ({kind}): {errors}")
    assert model.target_kind == kind
    for key, bound in bounds.items():
        assert errors[key] < bound, (key, errors[key])
    assert abs(model.dhat0 - errors["d_star"]) < 0.02 * errors["d_star"]


def copy_teach(source, target, image=lambda t, message: message):
    """Copy a teach file through ``image(t, image_message_bytes) -> bytes or None`` (None drops it)."""
    from hbvs_cli.io.foxglove_scene import SIMULATION_EPOCH_NS  # where a simulated teach's clock starts
    from hbvs_cli.io.mcap import McapStream, McapWriter, read_metadata

    stream = McapStream(source)
    with open(target, "wb") as handle:
        writer = McapWriter(handle)
        first = True
        for message in stream:
            if first:
                for name in stream.metadata:
                    writer.metadata(name, read_metadata(stream, name))
                first = False
            data = message.data
            if message.topic == "/camera/image":
                data = image((message.log_time - SIMULATION_EPOCH_NS) * 1e-9, data)  # s from the start
                if data is None:
                    continue
            copy_message(writer, message, data=data)
        writer.finish()


def strip_frames(source, target, drop):
    """Copy a teach file, leaving out the images of frames where drop(t) is True."""
    copy_teach(source, target, lambda t, data: None if drop(t) else data)


def _painted_out(data: bytes) -> bytes:
    """A stored image (a serialized CompressedImage) with the target painted out."""
    from hbvs_cli.io.images import compressed_image_message, decode_image, encode_image, read_compressed_image

    stored = read_compressed_image(data)
    image = decode_image(stored.data)
    image[:260, :] = 150
    return compressed_image_message(stored.stamp_ns, encode_image(image), "png").SerializeToString()


def _cover_target(source, target, covered):
    """Copy a teach file, painting the target out of the images at times where covered(t)."""
    copy_teach(source, target, lambda t, data: _painted_out(data) if covered(t) else data)


def test_a_stretch_without_the_target_is_bridged_and_reported(default_teach, tmp_path):
    # Both kinds of stretch in one recording (one fit): 18 frames missing from the file
    # (8.0-8.6 s), and 15 frames present with the target covered (a detector blackout,
    # 12.0-12.5 s).
    gappy = tmp_path / "gappy.mcap"
    copy_teach(default_teach, gappy,
               lambda t, data: None if 8.0 <= t < 8.6 else (_painted_out(data) if 12.0 <= t < 12.5 else data))
    model = make_fit(gappy, tmp_path / "fit.mcap").model
    # Missing frames are not counted, covered ones are counted as lost.
    assert model.frames.total == 582 and model.frames.used == 567
    assert model.frames.lost == 15 and model.frames.longest_gap_s == pytest.approx(16 / 30, abs=1e-6)
    errors = fit_errors(model)
    assert errors["theta_deg"] < 0.1 and errors["x_hd2"] < 2e-3


def test_a_path_that_stops_halfway_warns_about_condition_35(tmp_path):
    csv = tmp_path / "stop.csv"
    # 3 s of driving, then 3 s stopped.
    rows = ["t,v,w"] + [f"{k / 10:.1f},{0.1 if k < 30 else 0.0},0.0" for k in range(60)]
    csv.write_text("\n".join(rows) + "\n")
    teach = make_teach(tmp_path / "teach.mcap", path=str(csv))
    result = call_hbvs("fit", str(teach), "-o", str(tmp_path / "fit.mcap"))
    assert result.returncode == 0
    warning = [line for line in result.stderr.decode().splitlines() if "warning" in line]
    assert any("condition (35)" in line and "stops" in line for line in warning), result.stderr.decode()
    model = read_fit_file(tmp_path / "fit.mcap").model
    assert model.condition35.stopped_fraction > 0.3
    assert model.condition35.min_abs_xhd1_dot < 0.002


def test_fit_of_a_video_recording_agrees_with_the_truth(video_fit):
    """Teach from a video of the simulated drive (the truth is known), then fit."""
    _, fit, world, profile, start, times = video_fit
    model = read_fit_file(fit).model
    errors = errors_against_drive(model, world, profile, start, times)
    assert model.world_description is None and model.taught_path is None
    assert errors["theta_deg"] < 0.05
    assert errors["x_hd1"] < 1e-3 and errors["x_hd2"] < 1e-3
    # No commands in a video: d* from the target's metric size (--target-size).
    d_star = errors["d_star"]
    assert model.dhat0_source == "target-size" and abs(model.dhat0 - d_star) < 0.02 * d_star


def test_fit_of_a_ros2_bag_agrees_with_the_truth(video_fit, tmp_path):
    """The video teach's frames (JPEG, as a camera driver's compressed topic carries them)
    in a ROS 2 bag with its CameraInfo: taught from the bag and fitted, they agree with the
    truth as the video does."""
    from test_stage_teach import write_bag

    from hbvs_cli.io.images import read_compressed_image
    from hbvs_cli.io.mcap import McapStream

    video_teach, _, world, profile, start, times = video_fit
    stored = [read_compressed_image(m.data) for m in McapStream(video_teach, topics={"/camera/image"})]
    assert len(stored) == 600 and {image.format for image in stored} == {"jpeg"}
    write_bag(tmp_path / "bag", [image.data for image in stored])
    teach = make_teach(tmp_path / "bag.mcap", bag=tmp_path / "bag")
    make_fit(teach, tmp_path / "fit.mcap", target_size=target_size(world))
    model = read_fit_file(tmp_path / "fit.mcap").model
    errors = errors_against_drive(model, world, profile, start, times)
    assert errors["theta_deg"] < 0.05
    assert errors["x_hd1"] < 1e-3 and errors["x_hd2"] < 1e-3


def test_bad_input_one_line_nonzero_exit_no_output(short_teach, tmp_path):
    not_mcap = tmp_path / "notes.txt"
    not_mcap.write_text("not an mcap file\n")
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(short_teach.read_bytes()[:3000])
    no_images = tmp_path / "noimages.mcap"
    strip_frames(short_teach, no_images, lambda t: True)
    from hbvs_cli.io.mcap import McapStream, McapWriter, read_metadata

    no_calibration = tmp_path / "nocal.mcap"
    stream = McapStream(short_teach, topics={"/camera/image"})
    with open(no_calibration, "wb") as handle:
        writer = McapWriter(handle)
        for k, message in enumerate(stream):
            if k == 0:
                writer.metadata("hbvs", read_metadata(stream, "hbvs"))
            copy_message(writer, message)
            if k > 20:
                break
        writer.finish()
    never_found = tmp_path / "never.mcap"  # its first second, the target covered throughout
    copy_teach(short_teach, never_found, lambda t, data: _painted_out(data) if t < 1.0 else None)
    cases = [
        ([str(not_mcap)], 3, "not"),
        ([str(truncated)], 3, ""),
        ([str(no_images)], 3, "no complete image"),
        ([str(no_calibration)], 3, "calibration"),
        ([str(never_found)], 3, "not found"),
        ([str(short_teach), "--reference", "9999"], 2, "out of range"),
        ([str(short_teach), "--smoothing", "lots"], 2, "smoothing"),
        ([str(tmp_path / "missing.mcap")], 3, "no such file"),
    ]
    output = tmp_path / "out.mcap"
    for k, (args, code, words) in enumerate(cases):
        # The first case as a user runs it; the others in this process (same code path, faster).
        result = (run_hbvs if k == 0 else call_hbvs)("fit", *args, "-o", str(output), "-q")
        lines = result.stderr.decode().strip().splitlines()
        assert result.returncode == code, (args, result.stderr)
        assert len(lines) == 1 and lines[0].startswith("hbvs: error:") and words in lines[0], (args, lines)
        assert not output.exists() and not list(tmp_path.glob("out.mcap*.partial"))


def test_reference_last_and_index(default_teach, short_teach, tmp_path):
    last = make_fit(default_teach, tmp_path / "last.mcap", reference="last").model
    # An index inside the drive: the 6 s teach's middle (the same choice of reference).
    middle = make_fit(short_teach, tmp_path / "mid.mcap", reference="90").model
    assert last.reference_index == 599 and middle.reference_index == 90
    # F* at the last frame is 2 m from the wall: d* follows.
    assert abs(last.dhat0 - 2.0) < 0.04
    # Measured: last 0.006 deg, 3e-5 / 1e-4; the 6 s teach's middle 0.031 deg, 1.1e-4 / 5.0e-4.
    for model in (last, middle):
        errors = fit_errors(model)
        assert errors["theta_deg"] < 0.05 and errors["x_hd1"] < 1e-3 and errors["x_hd2"] < 1e-3


def test_a_reference_index_with_a_leading_zero_keeps_that_frames_image(short_teach, tmp_path):
    """``--reference 090`` is frame 90, as ``--reference 90`` is: its image is the fit's
    reference image (it used to be missed, and fit ended in an internal error, exit 70)."""
    from hbvs_cli.io.fit_file import read_fit_file

    padded = make_fit(short_teach, tmp_path / "padded.mcap", reference="090").model
    plain = make_fit(short_teach, tmp_path / "plain.mcap", reference="90").model
    assert padded.reference_index == plain.reference_index == 90
    image = read_fit_file(tmp_path / "padded.mcap").reference_image
    assert image is not None and image == read_fit_file(tmp_path / "plain.mcap").reference_image


def test_fit_reports_its_uncertainty_and_older_files_still_read(default_fit, tmp_path):
    """The fit file holds n*'s sigma and the splines' (model.uncertainty, theta_d_sigma and
    x_hd1_sigma on /desired/raw and /desired/smooth); the default scenario's actual theta_d
    error lies inside the reported 95 % interval. A model without the new record (an older
    fit file) still reads, and its figure has no band."""
    import json

    from hbvs_cli.io.fit_file import model_from_message, model_message
    from hbvs_cli.report.fit_plot import plot_fit, read_fit_signals

    path, model = default_fit
    uncertainty = model.uncertainty
    assert uncertainty.theta_d_sigma_deg is not None and uncertainty.x_hd1_sigma is not None
    assert uncertainty.calibration == "exact" and uncertainty.calibration_normal_sigma_deg == 0.0  # a simulated teach
    assert 0.0 < uncertainty.normal_sigma_deg < 0.5 and 0.0 < uncertainty.point_noise_px < 0.5
    signals = read_fit_signals(path)
    assert {"theta_d_sigma", "x_hd1_sigma"} <= set(signals.smooth)
    errors = fit_errors(model)
    assert np.radians(errors["theta_deg"]) <= 1.96 * float(np.max(signals.smooth["theta_d_sigma"]))
    older = json.loads(json.dumps(model_message(model, 0)))
    del older["uncertainty"]
    assert model_from_message(older, "older").uncertainty is None
    for key in ("theta_d_sigma", "x_hd1_sigma"):
        signals.smooth.pop(key)
    plot_fit(signals)  # no band, no error


def test_frames_decoded_while_the_target_is_picked_give_the_same_fit(tmp_path, monkeypatch):
    """Gray footage: while fit finds the board's pattern in the first frames (held here until
    30 frames are decoded), it decodes the frames after the first few, in gray as the detector wants
    them; the fit file is the same, byte for byte, as without reading ahead."""
    import threading
    import time

    from hbvs_cli.stages import fit as fit_stage
    from hbvs_cli.stages import frame_decoding

    teach = str(gray_footage_teach(tmp_path))
    decoded: list[tuple[int, bool]] = []
    decode = frame_decoding.decode_frame
    monkeypatch.setattr(frame_decoding, "decode_frame", lambda frame, name, colour=False: decoded.append((frame.index, colour)) or decode(frame, name, colour))
    pick, during_pick = fit_stage._detector_spec, []

    def held_pick(*args, **kwargs):
        assert threading.current_thread() is threading.main_thread()  # where a stop signal lands
        deadline = time.monotonic() + 30.0
        while len(decoded) < 30 and time.monotonic() < deadline:
            time.sleep(0.01)
        during_pick.extend(decoded)
        return pick(*args, **kwargs)

    monkeypatch.setattr(fit_stage, "_detector_spec", held_pick)
    assert call_hbvs("fit", teach, "--target", "chessboard", "-o", str(tmp_path / "ahead.mcap"), "-q").returncode == 0
    assert len(during_pick) >= 30
    # The first frames asked for colour (the target unknown), the ones after them gray.
    assert all(colour for index, colour in decoded if index < 5)
    assert not any(colour for index, colour in decoded if index >= 9)
    assert sorted(index for index, _ in decoded) == list(range(60))

    monkeypatch.setattr(fit_stage, "_detector_spec", pick)
    monkeypatch.setattr(fit_stage, "READ_AHEAD_BYTES", 0)
    decoded.clear()
    assert call_hbvs("fit", teach, "--target", "chessboard", "-o", str(tmp_path / "in_turn.mcap"), "-q").returncode == 0
    assert (tmp_path / "ahead.mcap").read_bytes() == (tmp_path / "in_turn.mcap").read_bytes()
    assert read_fit_file(tmp_path / "ahead.mcap").model.frames.used == 60


def test_the_solvers_are_loaded_while_reading_ahead_and_run_with_blas_on_one_thread(tmp_path, monkeypatch):
    """scipy's solvers (and scipy's own BLAS) are imported before the pick, while a second thread
    reads ahead, not at the start when nothing else runs; the fit runs them with every BLAS
    library on one thread, and the limits are restored after."""
    import threading

    from threadpoolctl import threadpool_info, threadpool_limits

    from hbvs_cli.stages import fit as fit_stage

    teach = str(gray_footage_teach(tmp_path))
    load, pick, fit_trajectory, steps = fit_stage._load_solvers, fit_stage._detector_spec, fit_stage.fit_desired_trajectory, []

    def loaded() -> None:
        steps.append(("load", threading.current_thread() is threading.main_thread()))
        load()

    def picked(*args, **kwargs):
        steps.append(("pick", threading.active_count() > 1))  # the reading thread runs
        return pick(*args, **kwargs)

    def fitted(*args, **kwargs):
        steps.append(("fit", all(library["num_threads"] == 1 for library in threadpool_info() if library["user_api"] == "blas")))
        return fit_trajectory(*args, **kwargs)

    monkeypatch.setattr(fit_stage, "_load_solvers", loaded)
    monkeypatch.setattr(fit_stage, "_detector_spec", picked)
    monkeypatch.setattr(fit_stage, "fit_desired_trajectory", fitted)
    with threadpool_limits(limits=2, user_api="blas"):  # as OPENBLAS_NUM_THREADS=2 would
        before = [(library["filepath"], library["num_threads"]) for library in threadpool_info()]
        assert call_hbvs("fit", teach, "--target", "chessboard", "-o", str(tmp_path / "fit.mcap"), "-q").returncode == 0
        after = {library["filepath"]: library["num_threads"] for library in threadpool_info()}
    assert steps == [("load", True), ("pick", True), ("load", True), ("fit", True)]
    assert any(threads == 2 for _, threads in before) and all(after[path] == threads for path, threads in before)


def test_an_error_met_while_reading_ahead_comes_after_the_frames_before_it():
    import threading

    from hbvs_cli.errors import InputError
    from hbvs_cli.stages.fit import _picked_while_reading

    ended = threading.Event()

    def frames():
        for index in range(3):
            yield index, b"", np.zeros((2, 2), np.uint8)
        ended.set()
        raise InputError("teach.mcap frame 3: cannot be decoded")

    spec, rest = _picked_while_reading(lambda: ended.wait(10.0) and "picked", frames(), 1 << 20)
    assert spec == "picked"
    seen = []
    with pytest.raises(InputError, match="frame 3"):
        for index, _, _ in rest:
            seen.append(index)
    assert seen == [0, 1, 2]
    # Within a budget of two frames' pixels, two are taken ahead; the rest follow in order.
    _, rest = _picked_while_reading(lambda: None, iter([(k, b"", np.zeros((2, 2), np.uint8)) for k in range(5)]), 8)
    assert [index for index, _, _ in rest] == list(range(5))


def test_a_stop_signal_during_the_pick_stops_the_reading_thread_first():
    import threading

    from hbvs_cli.stages.fit import _picked_while_reading

    started = threading.Event()

    def endless():
        started.set()
        while True:
            yield 0, b"", np.zeros((2, 2), np.uint8)

    def interrupted_pick():
        started.wait(10.0)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _picked_while_reading(interrupted_pick, endless(), 1 << 40)
    assert not any(thread.name.startswith("hbvs-read-ahead") for thread in threading.enumerate())


def test_a_fit_given_the_layout_does_not_advise_giving_it():
    """With --target-points the uncertain-n* warning keeps its numbers and its advice on the
    drive, but no longer asks for --target-size or --target-points (issue 46)."""
    from hbvs_cli.core.desired import FitUncertainty, uncertainty_warning
    from hbvs_cli.stages.fit import layout_given_warn

    flat = np.full(50, 1e-3)
    line = uncertainty_warning(FitUncertainty(normal_sigma_deg=1.5, point_noise_px=0.02, theta_sigma=flat, x_h1_sigma=flat,
                                              smooth_theta_sigma=flat, smooth_x_h1_sigma=flat))
    assert "--target-points FILE" in line
    told: list[str] = []
    layout_given_warn(told.append)(line)
    assert len(told) == 1 and "uncertain by 1.5 deg" in told[0] and "--reference last" in told[0] and "curves" in told[0]
    assert "--target-size" not in told[0] and "--target-points FILE" not in told[0] and "layout is given (--target-points)" in told[0]


def test_a_size_that_puts_d_star_out_of_repeats_bounds_is_refused_by_the_fit(tmp_path):
    """--target-size in millimetres by mistake: d* of 2e9 m would pass the fit and fail in
    repeat on an option never given; the fit refuses it in one line, writing nothing."""
    output = tmp_path / "fit.mcap"
    result = call_hbvs("fit", str(SAMPLES / "teach.mcap"), "--target-size", "1e9", "-o", str(output))
    lines = result.stderr.decode().strip().splitlines()
    assert result.returncode == 3 and len(lines) == 1 and "outside the 0.001 to 1000 m" in lines[0] and "--target-size" in lines[0]
    assert not output.exists() and list(tmp_path.iterdir()) == []
