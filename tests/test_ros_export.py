"""``hbvs export`` (issue 14): hbvs files as ROS 2 bags, read back with rosbags' AnyReader.

evo itself is not a test dependency (it pulls pandas, seaborn and a GUI stack); its APE
without alignment is the RMS of the position differences of the two pose topics matched by
stamp, computed here from the poses read back through AnyReader and compared with
``hbvs report --json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, call_hbvs, make_run, run_hbvs

pytest.importorskip("rosbags")

from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from hbvs_cli.io import topics  # noqa: E402

SAMPLES = REPO / "samples"


def read_bag(path: Path) -> dict[str, list[tuple[int, object]]]:
    """Every message of a bag by topic: (bag time ns, decoded message)."""
    messages: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for connection, stamp, raw in reader.messages():
            messages.setdefault(connection.topic, []).append((stamp, reader.deserialize(raw, connection.msgtype)))
        types = {c.topic: c.msgtype for c in reader.connections}
    messages["__types__"] = types  # type: ignore[assignment]
    return messages


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("export")
    run = folder / "run.mcap"
    make_run(SAMPLES / "fit.mcap", run, sim=True, perception="points", pixel_noise=0.3, record_images=False)
    return run


def test_run_exports_commands_poses_path_and_tf(sim_run, tmp_path):
    from hbvs_cli.io.run_file import read_run

    bag = tmp_path / "run_bag"
    result = run_hbvs("export", str(sim_run), "-o", str(bag))
    assert result.returncode == 0, result.stderr.decode()
    assert (bag / "metadata.yaml").is_file() and not list(tmp_path.glob("*.partial"))
    run = read_run(sim_run)
    K = run.steps
    bagged = read_bag(bag)
    types = bagged.pop("__types__")
    assert types == {
        topics.ROS_CMD_VEL_TOPIC: topics.ROS_TWIST_SCHEMA, topics.ROS_TRUE_POSE_TOPIC: topics.ROS_POSE_STAMPED_SCHEMA,
        topics.ROS_DESIRED_POSE_TOPIC: topics.ROS_POSE_STAMPED_SCHEMA, topics.ROS_TAUGHT_PATH_TOPIC: topics.ROS_PATH_SCHEMA,
        topics.ROS_TF_TOPIC: topics.ROS_TF_SCHEMA, topics.ROS_TF_STATIC_TOPIC: topics.ROS_TF_SCHEMA,
    }
    counts = {topic: len(items) for topic, items in bagged.items()}
    assert counts == {
        topics.ROS_CMD_VEL_TOPIC: K, topics.ROS_TRUE_POSE_TOPIC: K, topics.ROS_DESIRED_POSE_TOPIC: K,
        topics.ROS_TAUGHT_PATH_TOPIC: 1, topics.ROS_TF_TOPIC: K, topics.ROS_TF_STATIC_TOPIC: 1,
    }
    # Original stamps: bag time = header stamp = the run file's log time, to the nanosecond.
    from hbvs_cli.io.mcap import McapStream

    step_ns = np.array([m.log_time for m in McapStream(sim_run, topics={topics.STATE_TOPIC})], dtype=np.int64)
    assert step_ns.size == K
    for topic in (topics.ROS_TRUE_POSE_TOPIC, topics.ROS_DESIRED_POSE_TOPIC):
        assert [t for t, _ in bagged[topic]] == step_ns.tolist()
        assert [stamp_ns(m.header) for _, m in bagged[topic]] == step_ns.tolist()
    # Values: the commands sent, the poses as recorded (exact float64 copies).
    v = np.array([m.linear.x for _, m in bagged[topics.ROS_CMD_VEL_TOPIC]])
    w = np.array([m.angular.z for _, m in bagged[topics.ROS_CMD_VEL_TOPIC]])
    assert np.array_equal(v, run.state["v_c"]) and np.array_equal(w, run.state["w_c"])
    true_xy = np.array([[m.pose.position.x, m.pose.position.y] for _, m in bagged[topics.ROS_TRUE_POSE_TOPIC]])
    assert np.array_equal(true_xy, run.true_pose[:, :2])
    yaw = np.array([2 * np.arctan2(m.pose.orientation.z, m.pose.orientation.w) for _, m in bagged[topics.ROS_TRUE_POSE_TOPIC]])
    assert np.max(np.abs(np.angle(np.exp(1j * (yaw - run.true_pose[:, 2]))))) < 1e-12
    path = bagged[topics.ROS_TAUGHT_PATH_TOPIC][0][1]
    assert len(path.poses) == K and path.header.frame_id == "world"
    # /tf: world -> base_link on the floor under the true pose; base_link -> camera_optical once.
    tf = [m.transforms[0] for _, m in bagged[topics.ROS_TF_TOPIC]]
    assert {(t.header.frame_id, t.child_frame_id) for t in tf} == {("world", "base_link")}
    assert np.array_equal([[t.transform.translation.x, t.transform.translation.y] for t in tf], true_xy)
    assert all(t.transform.translation.z == 0.0 for t in tf)
    static = bagged[topics.ROS_TF_STATIC_TOPIC][0][1].transforms[0]
    assert (static.header.frame_id, static.child_frame_id) == ("base_link", "camera_optical")
    assert static.transform.translation.z == pytest.approx(bagged[topics.ROS_TRUE_POSE_TOPIC][0][1].pose.position.z)


def test_ape_of_the_exported_poses_agrees_with_the_report(sim_run, tmp_path):
    """evo_ape's measure (translation, no alignment) on the bag = the report's position rmse."""
    bag = tmp_path / "bag"
    assert call_hbvs("export", str(sim_run), "-o", str(bag)).returncode == 0
    bagged = read_bag(bag)
    repeated = {stamp_ns(m.header): m.pose.position for _, m in bagged[topics.ROS_TRUE_POSE_TOPIC]}
    taught = {stamp_ns(m.header): m.pose.position for _, m in bagged[topics.ROS_DESIRED_POSE_TOPIC]}
    common = sorted(set(repeated) & set(taught))
    assert len(common) == len(repeated) == len(taught)
    d = np.array([[repeated[t].x - taught[t].x, repeated[t].y - taught[t].y, repeated[t].z - taught[t].z] for t in common])
    ape_rmse = float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
    report = json.loads(call_hbvs("report", str(sim_run), "--json").stdout)
    report_rmse = report["pose_error"]["position_m"]["rmse"]
    assert ape_rmse > 0.001
    assert abs(ape_rmse - report_rmse) <= 0.02 * report_rmse
    # Measured: they agree to the report's 7 significant digits.
    assert ape_rmse == pytest.approx(report_rmse, rel=1e-6)


def test_teach_with_images_exports_images_camera_info_and_the_taught_path(tmp_path):
    from hbvs_cli.io.teach_file import TeachReader

    bag = tmp_path / "teach_bag"
    assert call_hbvs("export", str(SAMPLES / "teach.mcap"), "-o", str(bag), "-q").returncode == 0
    reader = TeachReader(SAMPLES / "teach.mcap")
    frames = [(f.log_time_ns, f.stored_image().data, f.command) for f in reader.frames()]
    bagged = read_bag(bag)
    images = bagged[topics.ROS_IMAGE_TOPIC]
    infos = bagged[topics.ROS_CAMERA_INFO_TOPIC]
    assert len(images) == len(infos) == len(frames) == 200
    for (t, image), (t_info, info), (log_time, data, _) in zip(images, infos, frames):
        assert t == t_info == log_time == stamp_ns(image.header) == stamp_ns(info.header)
        assert bytes(image.data) == data and image.format == "jpeg" and image.header.frame_id == "camera_optical"
    camera = reader.camera
    info = infos[0][1]
    assert (info.width, info.height) == (camera.width, camera.height) == (320, 240)
    assert np.array_equal(info.k.reshape(3, 3), camera.K) and info.header.frame_id == "camera_optical"
    commands = [m for _, m in bagged[topics.ROS_CMD_VEL_TOPIC]]
    assert [(m.linear.x, m.angular.z) for m in commands] == [c for _, _, c in frames]
    assert len(bagged[topics.ROS_TAUGHT_PATH_TOPIC][0][1].poses) == 200


def test_fit_exports_the_reference_image_and_the_integrated_taught_path(tmp_path):
    from hbvs_cli.io.fit_file import read_fit_file
    from hbvs_cli.io.teach_file import TeachReader

    bag = tmp_path / "fit_bag"
    assert call_hbvs("export", str(SAMPLES / "fit.mcap"), "-o", str(bag), "-q").returncode == 0
    bagged = read_bag(bag)
    fit = read_fit_file(SAMPLES / "fit.mcap")
    assert bytes(bagged[topics.ROS_REFERENCE_IMAGE_TOPIC][0][1].data) == fit.reference_image
    path = bagged[topics.ROS_TAUGHT_PATH_TOPIC][0][1]
    # The path integrated from the taught commands is the teach's true poses.
    true_poses = np.array([f.pose for f in TeachReader(SAMPLES / "teach.mcap").frames()])
    xy = np.array([[p.pose.position.x, p.pose.position.y] for p in path.poses])
    assert xy.shape == (200, 2)
    assert np.max(np.abs(xy - true_poses[:, :2])) < 1e-9


def test_export_is_atomic_and_refuses_what_it_must_not_replace(sim_run, tmp_path):
    bag = tmp_path / "bag"
    assert call_hbvs("export", str(sim_run), "-o", str(bag)).returncode == 0
    first = (bag / "metadata.yaml").read_bytes()
    # An existing bag is replaced whole, and the same input gives the same bag.
    assert call_hbvs("export", str(sim_run), "-o", str(bag)).returncode == 0
    assert (bag / "metadata.yaml").read_bytes() == first and len(list(bag.iterdir())) == 2
    # A folder that is not a bag, a file, stdout: refused with one line, exit 2, kept.
    keep = tmp_path / "photos"
    keep.mkdir()
    (keep / "a.jpg").write_bytes(b"x")
    for target in (str(keep), str(sim_run), "-"):
        result = call_hbvs("export", str(sim_run), "-o", target)
        assert result.returncode == 2, result.stderr
        assert len(result.stderr.decode().strip().splitlines()) == 1
    assert (keep / "a.jpg").read_bytes() == b"x"
    # A file that is not an hbvs file: exit 3, nothing left behind.
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not mcap")
    result = call_hbvs("export", str(junk), "-o", str(tmp_path / "new_bag"))
    assert result.returncode == 3 and not (tmp_path / "new_bag").exists()
    assert not list(tmp_path.glob("*.partial"))


def test_export_removes_only_the_partials_hbvs_left(sim_run, tmp_path):
    """``export -o P`` clears what a killed export left beside P (its pid dead, its folder
    holding only the bag), never a user's folder named alike (issue 46): a token hbvs never
    writes (``cafe``, ``ab``), a pid above pid_max, or contents of the user's own."""
    import subprocess

    dead = subprocess.Popen(["true"])
    dead.wait()                                          # a pid this system gave, now free
    pid_max = int(Path("/proc/sys/kernel/pid_max").read_text())
    bag = tmp_path / "P"
    kept = [tmp_path / f"P.{dead.pid}-cafe.partial", tmp_path / f"P.{pid_max + 1}-ab.partial",
            tmp_path / f"P.{pid_max + 1}-0123abcd.partial", tmp_path / f"P.{dead.pid}-89abcdef.partial"]
    for folder in kept:
        folder.mkdir()
        (folder / "notes.txt").write_text("mine")
    (kept[2] / "notes.txt").unlink()
    (kept[2] / "P").mkdir()                              # hbvs's layout, but no pid ever had that number
    stale = tmp_path / f"P.{dead.pid}-76543210.partial"
    (stale / "P").mkdir(parents=True)
    (stale / "P" / "half.db3").write_bytes(b"\0" * 10)
    result = run_hbvs("export", str(sim_run), "-o", str(bag))
    assert result.returncode == 0, result.stderr.decode()
    assert (bag / "metadata.yaml").is_file() and not stale.exists()
    assert all(folder.is_dir() for folder in kept)
    assert [(kept[i] / "notes.txt").read_text() for i in (0, 1, 3)] == ["mine"] * 3
