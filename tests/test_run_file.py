"""The run file's writer and reader live together (io/run_file.py): what one writes, the other reads."""

from __future__ import annotations

import math

import numpy as np

from hbvs_cli.core.camera import DEFAULT_CAMERA
from hbvs_cli.io.images import bytes_to_store
from hbvs_cli.io.mcap import McapStream, open_output
from hbvs_cli.io.messages import LOG_WARNING
from hbvs_cli.io.run_file import STATE_FIELDS, RunWriter, read_run
from hbvs_cli.io.topics import ANNOTATIONS_TOPIC, CALIBRATION_TOPIC, IMAGE_TOPIC


def test_what_the_run_writer_writes_the_reader_reads_back(tmp_path):
    path = tmp_path / "run.mcap"
    rng = np.random.default_rng(7)
    steps = 5
    values = [{key: float(rng.normal()) for key in STATE_FIELDS if key != "t"} for _ in range(steps)]
    values[2]["e1"] = math.nan  # written as null, read back as NaN
    poses = rng.normal(size=(steps, 2, 3))
    with open_output(str(path)) as writer:
        run = RunWriter(writer, {"file_kind": "run", "mode": "sim", "law": "paper", "d_true": 2.5}, DEFAULT_CAMERA)
        run.event(0.1, LOG_WARNING, "target lost (occluded)")
        for k in range(steps):
            t = k / 30
            run.state(t, values[k] | {"saturated": k == 1, "target_lost": k == 3, "lost_reason": "occluded" if k == 3 else "",
                                      "frame_dropped": k == 4})
            run.command(t, values[k]["v_c"], values[k]["w_c"], k == 1)
            run.poses(t, poses[k, 0], poses[k, 1], 1.0)
        image = np.full((DEFAULT_CAMERA.height, DEFAULT_CAMERA.width), 128, np.uint8)
        run.image(0.0, *bytes_to_store(image), np.array([[10.0, 20.0]]), np.array([[11.0, 21.0]]), "t = 0.00 s")
    data = read_run(path)
    assert data.steps == steps and data.info["law"] == "paper" and data.info["d_true"] == 2.5
    assert np.array_equal(data.state["t"], np.arange(steps) / 30)
    for key in STATE_FIELDS[1:]:
        expected = np.array([v[key] for v in values])
        assert np.array_equal(data.state[key], expected, equal_nan=True), key
    assert data.saturated.tolist() == [False, True, False, False, False]
    assert data.lost.tolist() == [False, False, False, True, False] and data.lost_reason[3] == "occluded"
    assert data.dropped.tolist() == [False, False, False, False, True]
    # The yaw goes through a quaternion and back: equal to rounding.
    assert np.allclose(data.true_pose, poses[:, 0], rtol=0, atol=1e-12) and np.allclose(data.desired_pose, poses[:, 1], rtol=0, atol=1e-12)
    assert data.events == [(0.1, LOG_WARNING, "target lost (occluded)")]
    topics = {message.topic for message in McapStream(str(path))}
    assert {CALIBRATION_TOPIC, IMAGE_TOPIC, ANNOTATIONS_TOPIC} <= topics
