"""Foxglove (issue 14): official schemas and the 3D scene.

* Every ``foxglove.*`` message of every file kind validates against Foxglove's own JSON
  schemas, vendored from ``@foxglove/schemas`` (hbvs_cli/io/foxglove_schemas.json); the
  schema stored in the file is that one, byte for byte once parsed; the protobuf images
  parse with Foxglove's published protobuf classes and carry their descriptor.
* The vendored JSON schemas agree field for field with the protobuf definitions that
  Foxglove publishes on PyPI (foxglove-schemas-protobuf): two official sources, one format.
* The 3D topics are consistent: world -> base_link is the true pose, camera_optical has its
  z along the robot's x, and the target points of the scene, carried through the published
  transforms into camera_optical and projected with the published CameraCalibration, land
  on the pixels hbvs's own camera model gives.
"""

from __future__ import annotations

import base64
import json

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from conftest import make_fit, make_run, make_teach
from hbvs_cli.io import topics
from hbvs_cli.io.schemas import FOXGLOVE_SCHEMAS, SCHEMAS
from hbvs_cli.sim.world import World


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


def test_vendored_schemas_name_their_source_and_cover_every_foxglove_topic():
    from pathlib import Path

    import hbvs_cli.io.schemas

    vendored = json.loads(Path(hbvs_cli.io.schemas.__file__).with_name("foxglove_schemas.json").read_text())
    assert vendored["package"] == "@foxglove/schemas" and vendored["version"] == "2.1.0" and len(vendored["tarball_sha256"]) == 64
    used = {schema for kind in topics.TOPICS.values() for schema in kind.values() if schema.startswith("foxglove.")}
    assert used == set(FOXGLOVE_SCHEMAS) == set(vendored["schemas"])
    for name, schema in FOXGLOVE_SCHEMAS.items():
        assert schema["title"] == name and "foxglove-sdk" in schema["$comment"]


def _proto_fields(descriptor) -> dict:
    """Field names of a protobuf message, nested messages expanded (Timestamp/Duration kept as leaves)."""
    fields = {}
    for field in descriptor.fields:
        sub = field.message_type
        if sub is not None and sub.full_name.startswith("foxglove."):
            fields[field.name] = _proto_fields(sub)
        else:
            fields[field.name] = None
    return fields


def _json_fields(schema: dict) -> dict:
    target = schema.get("items", schema)
    fields = {}
    for name, sub in target.get("properties", {}).items():
        inner = sub.get("items", sub)
        nested = inner.get("title", "").startswith("foxglove.") and "properties" in inner
        fields[name] = _json_fields(inner) if nested else None
    return fields


@pytest.mark.parametrize("name", sorted(FOXGLOVE_SCHEMAS))
def test_vendored_json_schemas_match_foxgloves_protobuf_definitions(name):
    import importlib

    module = importlib.import_module(f"foxglove_schemas_protobuf.{name.split('.')[1]}_pb2")
    descriptor = getattr(module, name.split(".")[1]).DESCRIPTOR
    assert _json_fields(FOXGLOVE_SCHEMAS[name]) == _proto_fields(descriptor)


@pytest.mark.parametrize("kind", ["teach", "fit", "run"])
def test_every_message_validates_against_the_official_schemas(files, kind):
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from mcap_protobuf.schema import build_file_descriptor_set

    official_descriptor = build_file_descriptor_set(CompressedImage).SerializeToString()
    validators = {name: jsonschema.Draft202012Validator(schema) for name, schema in SCHEMAS.items()}
    counts: dict[str, int] = {}
    for schema, channel, message in read_all(files[kind]):
        assert topics.TOPICS[kind][channel.topic] == schema.name
        if channel.message_encoding == "protobuf":
            assert schema.name == topics.COMPRESSED_IMAGE_SCHEMA and schema.data == official_descriptor
            image = CompressedImage.FromString(message.data)
            decoded = {
                "timestamp": {"sec": image.timestamp.seconds, "nsec": image.timestamp.nanos}, "frame_id": image.frame_id,
                "data": base64.b64encode(image.data).decode(), "format": image.format,
            }
        else:
            assert json.loads(schema.data) == SCHEMAS[schema.name]
            decoded = json.loads(message.data)
        validators[schema.name].validate(decoded)
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
    for _, channel, message in messages:
        if channel.message_encoding == "json":
            by_topic.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
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
    state_fields = set(SCHEMAS[topics.CONTROLLER_STATE_SCHEMA]["properties"])
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
