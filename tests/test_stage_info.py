"""``hbvs info FILE``: kind, duration, frames, target, settings and topics of a file."""

from __future__ import annotations

import json

import pytest

from conftest import SAMPLES, call_hbvs, make_run, make_teach


@pytest.fixture(scope="module")
def short_teach(tmp_path_factory):
    """A simulated teach of 2 s at 30 frames per second (ArUco target), in several chunks."""
    return make_teach(tmp_path_factory.mktemp("info") / "teach.mcap", duration=2.0, fps=30.0, target="aruco")


def info_json(*args: str) -> dict:
    result = call_hbvs("info", *args, "--json")
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def topic_counts(document: dict) -> dict[str, int]:
    return {topic["topic"]: topic["messages"] for topic in document["topics"]}


def test_a_simulated_teach(short_teach):
    document = info_json(str(short_teach))
    assert document["kind"] == "teach" and document["complete"] and document["target"] == "aruco"
    assert document["frames"] == 60 and document["duration_s"] == pytest.approx(59 / 30, abs=1e-6)
    assert document["settings"]["sim"] is True and document["metadata"]["source"] == "sim"
    counts = topic_counts(document)
    assert counts["/camera/image"] == counts["/teach/cmd_vel"] == counts["/ground_truth/pose"] == 60
    assert counts["/camera/calibration"] == 1 and document["messages"] == sum(counts.values())
    schemas = {topic["topic"]: (topic["schema"], topic["schema_encoding"]) for topic in document["topics"]}
    assert schemas["/camera/image"] == ("foxglove.CompressedImage", "protobuf")
    assert schemas["/teach/cmd_vel"] == ("hbvs.VelocityCommand", "jsonschema")


def test_the_sample_fit_and_a_run_of_it(tmp_path):
    from hbvs_cli.io.fit_file import read_fit_file

    model = read_fit_file(SAMPLES / "fit.mcap").model
    fit = info_json(str(SAMPLES / "fit.mcap"))
    assert fit["kind"] == "fit" and fit["target"] == model.target_kind
    assert fit["frames"] == topic_counts(fit)["/desired/raw"] == topic_counts(fit)["/desired/smooth"] > 0
    assert topic_counts(fit)["/fit/model"] == 1

    make_run(SAMPLES / "fit.mcap", tmp_path / "run.mcap", sim=True, perception="points", law="paper")
    run = info_json(str(tmp_path / "run.mcap"))
    assert run["kind"] == "run" and run["metadata"]["mode"] == "sim" and run["metadata"]["law"] == "paper"
    assert run["frames"] == topic_counts(run)["/repeat/state"] == topic_counts(run)["/repeat/cmd_vel"] > 0
    assert run["settings"]["perception"] == "points"
    # The text form names the same things, one per line.
    text = call_hbvs("info", str(tmp_path / "run.mcap")).stdout.decode()
    assert "kind" in text and "run (hbvs" in text and f"steps     {run['frames']}" in text
    assert "/repeat/state" in text and "hbvs.ControllerState" in text


def test_stdin_and_a_file_cut_off_by_a_crash(short_teach):
    data = short_teach.read_bytes()
    whole = call_hbvs("info", "-", "--json", input=data)
    assert whole.returncode == 0 and json.loads(whole.stdout)["file"] == "stdin"
    cut = call_hbvs("info", "-", "--json", input=data[: len(data) // 2])
    assert cut.returncode == 0, cut.stderr
    document = json.loads(cut.stdout)
    assert not document["complete"] and document["stop_reason"]
    assert 0 < topic_counts(document).get("/camera/image", 0) < 60
    assert b"the rest is lost" in cut.stderr


def test_what_is_not_an_mcap_file_exits_3(tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "bag_0.mcap").write_bytes(b"")
    folder = call_hbvs("info", str(tmp_path / "bag"))
    assert folder.returncode == 3 and b"give its storage file" in folder.stderr and b"bag_0.mcap" in folder.stderr
    (tmp_path / "notes.txt").write_text("not a recording\n")
    for path in (tmp_path / "notes.txt", tmp_path / "missing.mcap"):
        result = call_hbvs("info", str(path))
        assert result.returncode == 3 and result.stderr.decode().count("\n") == 1 and not result.stdout
