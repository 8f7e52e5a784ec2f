"""``hbvs fit``: desired signals against the truth, gaps, condition (35), bad input."""

from __future__ import annotations

import io

import numpy as np
import pytest

from hbvs_cli.io.fit_file import read_fit_file

from conftest import (
    call_hbvs,
    errors_against_drive,
    fit_errors,
    make_fit,
    make_teach,
    rendered_s_curve,
    run_hbvs,
    teach_from_rendered_video,
)

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
    assert model.frames["used"] == 600 and model.frames["lost"] == 0


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


def test_fit_is_deterministic_and_streams_from_stdin(default_teach, default_fit):
    from hbvs_cli.io.mcap import McapStream, read_metadata

    # The same teach through a pipe, in another process: message for message the same fit
    # as the session's (only the recorded input name differs: "-").
    result = run_hbvs("fit", "-", "-o", "-", "-q", input=default_teach.read_bytes())
    assert result.returncode == 0, result.stderr

    def contents(source):
        stream = McapStream(source)
        messages = [(m.topic, m.schema_name, m.log_time, m.data) for m in stream]
        metadata = read_metadata(stream, "hbvs")
        names = (metadata.pop("input"), metadata["settings"].pop("input"))
        return messages, metadata, names

    piped, reference = contents(io.BytesIO(result.stdout)), contents(default_fit[0])
    assert len(piped[0]) > 600 and piped[:2] == reference[:2]
    assert piped[2] == ("stdin", "-") and reference[2][0].endswith("teach.mcap")


def test_the_summary_table_goes_to_stderr(default_teach, tmp_path):
    result = run_hbvs("fit", str(default_teach), "-o", str(tmp_path / "f.mcap"))
    text = result.stderr.decode()
    assert result.returncode == 0 and result.stdout == b""
    for words in ("frames used / total", "600 / 600", "d* from taught commands", "condition (35)", "lambda"):
        assert words in text


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
            writer.copy(message, data=data)
        writer.finish()


def strip_frames(source, target, drop):
    """Copy a teach file, leaving out the images of frames where drop(t) is True."""
    copy_teach(source, target, lambda t, data: None if drop(t) else data)


def _cover_target(source, target, covered):
    """Copy a teach file, painting the target out of the images at times where covered(t)."""
    from hbvs_cli.io.images import compressed_image_message, decode_image, encode_image, read_compressed_image

    def paint(t, data):
        if not covered(t):
            return data
        stored = read_compressed_image(data)
        image = decode_image(stored.data)
        image[:260, :] = 150
        return compressed_image_message(stored.stamp_ns, encode_image(image), "png").SerializeToString()

    copy_teach(source, target, paint)


def test_a_stretch_without_the_target_is_bridged_and_reported(default_teach, tmp_path):
    gappy = tmp_path / "gappy.mcap"
    strip_frames(default_teach, gappy, lambda t: 8.0 <= t < 8.6)  # 18 frames missing
    summary = make_fit(gappy, tmp_path / "fit.mcap")
    model = summary.model
    assert model.frames["total"] == 582 and model.frames["used"] == 582
    # Detector blackout instead: frames present but the target covered.
    blank = tmp_path / "blank.mcap"
    _cover_target(default_teach, blank, lambda t: 12.0 <= t < 12.5)
    model = make_fit(blank, tmp_path / "fit2.mcap").model
    assert model.frames["lost"] == 15 and model.frames["longest_gap_s"] == pytest.approx(16 / 30, abs=1e-6)
    errors = fit_errors(model)
    assert errors["theta_deg"] < 0.1 and errors["x_hd2"] < 2e-3


def test_a_path_that_stops_halfway_warns_about_condition_35(tmp_path):
    csv = tmp_path / "stop.csv"
    rows = ["t,v,w"] + [f"{k / 10:.1f},{0.1 if k < 50 else 0.0},0.0" for k in range(100)]
    csv.write_text("\n".join(rows) + "\n")
    teach = make_teach(tmp_path / "teach.mcap", path=str(csv))
    result = run_hbvs("fit", str(teach), "-o", str(tmp_path / "fit.mcap"))
    assert result.returncode == 0
    warning = [line for line in result.stderr.decode().splitlines() if "warning" in line]
    assert any("condition (35)" in line and "stops" in line for line in warning), result.stderr.decode()
    model = read_fit_file(tmp_path / "fit.mcap").model
    assert model.condition35["stopped_fraction"] > 0.3
    assert model.condition35["min_abs_xhd1_dot"] < 0.002


def test_fit_of_a_video_recording_agrees_with_the_truth(tmp_path):
    """Teach from a video of the simulated drive (the truth is known), then fit."""
    teach, world, profile, start, times = teach_from_rendered_video(tmp_path, seed=1)
    make_fit(teach, tmp_path / "fit.mcap", target_size=world.target.size)
    model = read_fit_file(tmp_path / "fit.mcap").model
    errors = errors_against_drive(model, world, profile, start, times)
    assert model.world_description is None and model.taught_path is None
    assert errors["theta_deg"] < 0.05
    assert errors["x_hd1"] < 1e-3 and errors["x_hd2"] < 1e-3
    # No commands in a video: d* from the target's metric size (--target-size).
    d_star = errors["d_star"]
    assert model.dhat0_source == "target-size" and abs(model.dhat0 - d_star) < 0.02 * d_star


def test_fit_of_a_ros2_bag_agrees_with_the_truth(tmp_path):
    from test_stage_teach import write_bag

    world, profile, start, times, images = rendered_s_curve(seed=2)
    write_bag(tmp_path / "bag", list(images))
    teach = make_teach(tmp_path / "bag.mcap", bag=tmp_path / "bag")
    make_fit(teach, tmp_path / "fit.mcap", target_size=world.target.size)
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
            writer.copy(message)
            if k > 20:
                break
        writer.finish()
    never_found = tmp_path / "never.mcap"
    _cover_target(short_teach, never_found, lambda t: True)
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


def test_reference_last_and_index(default_teach, tmp_path):
    last = make_fit(default_teach, tmp_path / "last.mcap", reference="last").model
    middle = make_fit(default_teach, tmp_path / "mid.mcap", reference="300").model
    assert last.reference_index == 599 and middle.reference_index == 300
    # F* at the last frame is 2 m from the wall: d* follows.
    assert abs(last.dhat0 - 2.0) < 0.04
    for model in (last, middle):
        errors = fit_errors(model)
        assert errors["theta_deg"] < 0.05 and errors["x_hd1"] < 1e-3 and errors["x_hd2"] < 1e-3


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
    assert set(uncertainty) == {"normal_sigma_deg", "point_noise_px", "theta_d_sigma_deg", "x_hd1_sigma"}
    assert 0.0 < uncertainty["normal_sigma_deg"] < 0.5 and 0.0 < uncertainty["point_noise_px"] < 0.5
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
