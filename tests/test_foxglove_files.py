"""Foxglove (issues 14 and 27): Foxglove's own schemas and the 3D scene.

* Every ``foxglove.*`` message of every file kind is protobuf, on a channel whose schema is
  the FileDescriptorSet of the class Foxglove publishes (foxglove-schemas-protobuf), as
  mcap-protobuf-support writes it, and parses with that class; every ``hbvs.*`` message
  validates against its JSON schema.
* The 3D topics are consistent: world -> base_link is the true pose, camera_optical has its
  z along the robot's x, and the target points of the scene, carried through the published
  transforms into camera_optical and projected with the published CameraCalibration, land
  on the pixels hbvs's own camera model gives.
"""

from __future__ import annotations

import importlib
import json

import jsonschema
import numpy as np
import pytest
from google.protobuf.json_format import MessageToDict
from mcap.reader import make_reader
from mcap_protobuf.schema import build_file_descriptor_set
from scipy.spatial.transform import Rotation

from conftest import make_fit, make_run, make_teach
from hbvs_cli.io import topics
from hbvs_cli.io.schemas import HBVS_SCHEMAS
from hbvs_cli.sim.world import World


def foxglove_class(schema_name: str):
    name = schema_name.split(".", 1)[1]
    return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("foxglove")
    teach = make_teach(folder / "teach.mcap", duration=3.0)
    fit = folder / "fit.mcap"
    make_fit(teach, fit, copy_images=True)
    run = folder / "run.mcap"
    make_run(fit, run, sim=True, perception="points", pixel_noise=0.3, record_images=True)
    return {"teach": teach, "fit": fit, "run": run}


def read_all(path):
    with open(path, "rb") as handle:
        return [(schema, channel, message) for schema, channel, message in make_reader(handle).iter_messages()]


def decoded(schema, message) -> dict:
    """A message as a dict: JSON as it is, protobuf with its field names and every field."""
    if schema.encoding == "protobuf":
        return MessageToDict(foxglove_class(schema.name).FromString(message.data), preserving_proto_field_name=True,
                             always_print_fields_with_no_presence=True)
    return json.loads(message.data)


@pytest.mark.parametrize("kind", ["teach", "fit", "run"])
def test_every_message_validates_against_the_official_schemas(files, kind):
    validators = {name: jsonschema.Draft202012Validator(schema) for name, schema in HBVS_SCHEMAS.items()}
    counts: dict[str, int] = {}
    for schema, channel, message in read_all(files[kind]):
        assert topics.TOPICS[kind][channel.topic] == schema.name
        if schema.name.startswith("foxglove."):
            message_class = foxglove_class(schema.name)
            assert channel.message_encoding == schema.encoding == "protobuf"
            assert schema.data == build_file_descriptor_set(message_class).SerializeToString()
            decoded = message_class.FromString(message.data)
            assert decoded.SerializeToString(deterministic=True) == message.data
        else:
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            assert json.loads(schema.data) == HBVS_SCHEMAS[schema.name]
            validators[schema.name].validate(json.loads(message.data))
        counts[schema.name] = counts.get(schema.name, 0) + 1
    expected = {
        "teach": {"foxglove.CompressedImage", "foxglove.CameraCalibration", "foxglove.PoseInFrame", "foxglove.FrameTransform", "foxglove.SceneUpdate"},
        "fit": {"foxglove.CompressedImage", "foxglove.CameraCalibration", "foxglove.ImageAnnotations", "foxglove.FrameTransform", "foxglove.SceneUpdate"},
        "run": {"foxglove.CompressedImage", "foxglove.CameraCalibration", "foxglove.ImageAnnotations", "foxglove.PoseInFrame",
                "foxglove.FrameTransform", "foxglove.SceneUpdate"},
    }[kind]
    assert expected <= set(counts)
    if kind == "run":
        assert counts["foxglove.FrameTransform"] == counts["hbvs.ControllerState"] + 1


def test_the_3d_scene_is_consistent_with_the_camera_model(files):
    from hbvs_cli.io.fit_file import read_fit_file

    model = read_fit_file(files["fit"]).model
    messages = read_all(files["run"])
    by_topic: dict[str, list] = {}
    for schema, channel, message in messages:
        by_topic.setdefault(channel.topic, []).append((message.log_time, decoded(schema, message)))
    transforms = [m for _, m in by_topic[topics.TRANSFORM_TOPIC]]
    camera = [t for t in transforms if t["child_frame_id"] == "camera_optical"]
    robot = [(t["timestamp"], t) for t in transforms if t["child_frame_id"] == "base_link"]
    assert len(camera) == 1 and camera[0]["parent_frame_id"] == "base_link"
    optical = Rotation.from_quat([camera[0]["rotation"][k] for k in "xyzw"])
    # Optical convention: z forward = the robot's x, x right = -y, y down = -z.
    assert np.allclose(optical.apply([[0, 0, 1], [1, 0, 0], [0, 1, 0]]), [[1, 0, 0], [0, -1, 0], [0, 0, -1]], atol=1e-15)
    height = camera[0]["translation"]["z"]
    assert height == pytest.approx(World.from_dict(model.world_description).camera_height)
    poses = [m for _, m in by_topic[topics.TRUE_POSE_TOPIC]]
    assert len(robot) == len(poses)
    for (stamp, transform), pose in zip(robot, poses):
        assert stamp == pose["timestamp"] and transform["parent_frame_id"] == "world"
        assert (transform["translation"]["x"], transform["translation"]["y"], transform["translation"]["z"]) == (
            pose["pose"]["position"]["x"], pose["pose"]["position"]["y"], 0.0)
        assert transform["rotation"] == pose["pose"]["orientation"]
    # The target drawn in the scene, seen through the transforms and the published calibration.
    scene = by_topic[topics.SCENE_TOPIC][0][1]
    target = next(e for e in scene["entities"] if e["id"] == "target")
    path = next(e for e in scene["entities"] if e["id"] == "taught_path")
    assert target["frame_id"] == "world" and len(path["lines"][0]["points"]) == len(poses)
    points_world = np.array([[s["pose"]["position"][k] for k in "xyz"] for s in target["spheres"]])
    assert np.array_equal(points_world, World.from_dict(model.world_description).target.points_world)
    calibration = by_topic[topics.CALIBRATION_TOPIC][0][1]
    assert calibration["frame_id"] == "camera_optical"
    K = np.array(calibration["K"]).reshape(3, 3)
    worst = 0.0
    for (_, transform), pose in list(zip(robot, poses))[:: max(1, len(poses) // 10)]:
        base = Rotation.from_quat([transform["rotation"][k] for k in "xyzw"])
        t_base = np.array([transform["translation"][k] for k in "xyz"])
        in_base = base.inv().apply(points_world - t_base)
        in_optical = optical.inv().apply(in_base - [0.0, 0.0, height])
        assert np.all(in_optical[:, 2] > 0)  # in front of the camera
        projected = (K @ (in_optical / in_optical[:, 2:3]).T).T[:, :2]
        position, q = pose["pose"]["position"], pose["pose"]["orientation"]
        phi = 2 * np.arctan2(q["z"], q["w"])
        expected = World.from_dict(model.world_description).pixels(np.array([position["x"], position["y"], phi]))
        worst = max(worst, float(np.max(np.abs(projected - expected))))
    assert worst < 1e-6  # pixels


def test_the_shipped_layout_is_generated_and_names_only_what_run_files_hold():
    from conftest import REPO

    layout = json.loads((REPO / "docs" / "foxglove-layout.json").read_text())
    panels = layout["configById"]
    assert sorted(p.split("!")[0] for p in panels) == ["3D", "Image", "Plot", "Plot", "RosOut"]
    run_topics = topics.TOPICS["run"]
    state_fields = set(HBVS_SCHEMAS[topics.CONTROLLER_STATE_SCHEMA]["properties"])
    plotted = []
    for panel_id, config in panels.items():
        for series in config.get("paths", []):
            topic, field = series["value"].rsplit(".", 1)
            assert topic == topics.STATE_TOPIC and field in state_fields
            plotted.append(field)
        mode = config.get("imageMode", {})
        for topic in [config.get("topicToRender"), mode.get("imageTopic"), mode.get("calibrationTopic"),
                      *mode.get("annotations", {}), *config.get("topics", {})]:
            assert topic is None or topic in run_topics, (panel_id, topic)
    assert sorted(plotted) == ["dhat", "e1", "e3", "ebar2"]

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)
    # The file is what docs/make_foxglove_layout.py writes with the installed Foxglove SDK.
    pytest.importorskip("foxglove.layouts")
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_foxglove_layout", REPO / "docs" / "make_foxglove_layout.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.layout_text() == (REPO / "docs" / "foxglove-layout.json").read_text()


def test_stamps_start_at_the_documented_epoch_and_line_up_across_files(files, tmp_path):
    from hbvs_cli.io.foxglove_scene import SIMULATION_EPOCH_NS
    from hbvs_cli.io.run_file import read_run

    assert SIMULATION_EPOCH_NS == 1_067_212_800_000_000_000  # 2003-10-27 00:00:00 UTC
    times = {kind: {} for kind in files}
    for kind, path in files.items():
        for _, channel, message in read_all(path):
            times[kind].setdefault(channel.topic, []).append(message.log_time)
    assert min(times["teach"][topics.IMAGE_TOPIC]) == SIMULATION_EPOCH_NS
    assert min(min(t) for t in times["run"].values()) == SIMULATION_EPOCH_NS
    # The fit's annotations and images carry the teach images' stamps (Foxglove overlays them).
    assert times["fit"][topics.ANNOTATIONS_TOPIC] == times["teach"][topics.IMAGE_TOPIC] == times["fit"][topics.IMAGE_TOPIC]
    # Message stamps are the log times (2003, not 1970).
    for _, channel, message in read_all(files["run"]):
        if channel.topic == topics.STATE_TOPIC:
            stamp = json.loads(message.data)["timestamp"]
            assert stamp["sec"] * 10**9 + stamp["nsec"] == message.log_time
    # A replay keeps the stamps of the recording it replays; the report's clock still starts at 0.
    replay = tmp_path / "replay.mcap"
    make_run(files["fit"], replay, replay=files["teach"])
    state_times = [m.log_time for _, c, m in read_all(replay) if c.topic == topics.STATE_TOPIC]
    assert state_times == times["teach"][topics.IMAGE_TOPIC]
    assert read_run(replay).state["t"][0] == 0.0
