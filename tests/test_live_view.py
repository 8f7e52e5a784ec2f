"""``hbvs repeat --live`` (issue 14): the run served over Foxglove's WebSocket protocol by the
official SDK, on localhost, while it runs; the run file is unchanged.

A client (the ``websockets`` package) connects as the Foxglove app does, subscribes to every
advertised channel and checks that the channels are the run file's (topic, schema name,
encoding, schema bytes) and that every message it received is, byte for byte, the message
the file holds at that log time. Bounded: the run is paced at 5x real time (4 s) and every
wait has a timeout.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import re
import socket
import struct
import subprocess
import sys
import time

import pytest
from mcap.reader import make_reader

from conftest import REPO, make_run

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk's server speaks (the app offers it)
FIT = REPO / "samples" / "fit.mcap"
RUN_OPTIONS = ["--sim", "--perception", "points", "--pixel-noise", "0.3"]


#: The server's status messages the watch received (a miss names them).
STATUSES: list[dict] = []


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


async def watch(port: int, seconds: float, running=lambda: False) -> tuple[dict[int, dict], list[tuple[str, int, bytes]]]:
    """Every channel advertised and message received on ``port`` for ``seconds``; a silence of 2 s
    ends it early unless ``running()`` says the server's process is still at work (a loaded CI
    machine starves it for longer: a watch cut short there had not yet seen /tf)."""
    deadline = time.monotonic() + 30
    while True:
        try:
            connection = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=2)
            break
        except (OSError, asyncio.TimeoutError):
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.1)
    channels: dict[int, dict] = {}
    received: list[tuple[str, int, bytes]] = []
    async with connection:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                frame = await asyncio.wait_for(connection.recv(), timeout=2)
            except asyncio.TimeoutError:
                if running():
                    continue
                break
            except websockets.ConnectionClosed:
                break
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] == "advertise":
                    for channel in op["channels"]:
                        channels[channel["id"]] = channel
                    subscriptions = [{"id": c["id"], "channelId": c["id"]} for c in op["channels"]]
                    await connection.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
                elif op["op"] == "status":
                    STATUSES.append(op)
                    # foxglove-sdk sends a channel's advertise before it adds the channel to the client's
                    # map (connected_client.rs, advertise_channels): a subscribe that lands in between is
                    # refused as unknown. A robust client subscribes again; the channel is known by then.
                    unknown = re.fullmatch(r"Unknown channel ID: (\d+)", op.get("message", ""))
                    if unknown and int(unknown.group(1)) in channels:
                        await asyncio.sleep(0.05)
                        channel = int(unknown.group(1))
                        await connection.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": channel, "channelId": channel}]}))
            elif frame[0] == 0x01:  # message data: subscription id, log time, payload
                subscription, log_time = struct.unpack_from("<IQ", frame, 1)
                received.append((channels[subscription]["topic"], log_time, bytes(frame[13:])))
    return channels, received


def test_live_view_serves_the_run_files_channels_and_messages(tmp_path):
    port = free_port()
    live_run = tmp_path / "live.mcap"
    env = dict(os.environ, MPLBACKEND="Agg")
    process = subprocess.Popen(
        [sys.executable, "-m", "hbvs_cli", "repeat", str(FIT), *RUN_OPTIONS, "-o", str(live_run), "--foxglove", str(port), "--foxglove-speed", "5"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
    )
    try:
        channels, received = asyncio.run(watch(port, seconds=20, running=lambda: process.poll() is None))
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, stderr.decode()
    assert f"ws://127.0.0.1:{port}" in stderr.decode()
    file_channels: dict[str, tuple[str, str, str, bytes]] = {}
    file_messages: dict[tuple[str, int], bytes] = {}
    with open(live_run, "rb") as handle:
        for schema, channel, message in make_reader(handle).iter_messages():
            file_channels[channel.topic] = (schema.name, channel.message_encoding, schema.encoding, schema.data)
            file_messages[(channel.topic, message.log_time)] = message.data
    # The protocol sends binary (protobuf) schemas in base64, JSON schemas as text.
    advertised = {
        c["topic"]: (c["schemaName"], c["encoding"], c["schemaEncoding"],
                     base64.b64decode(c["schema"]) if c["schemaEncoding"] == "protobuf" else c["schema"].encode())
        for c in channels.values()
    }
    assert advertised == file_channels
    assert len(received) > 300
    counts = {topic: sum(1 for t, _, _ in received if t == topic) for topic in {t for t, _, _ in received}}
    assert set(counts) >= {"/repeat/state", "/repeat/cmd_vel", "/ground_truth/pose", "/desired/pose", "/tf"}, (
        counts, sorted(c["topic"] for c in channels.values()), STATUSES)
    assert all(file_messages[(topic, log_time)] == payload for topic, log_time, payload in received)
    # The run file is the one written without --live, byte for byte.
    plain = tmp_path / "plain.mcap"
    make_run(FIT, plain, sim=True, perception="points", pixel_noise=0.3)
    assert plain.read_bytes() == live_run.read_bytes()
    # -o - with --live: stdout carries the same bytes, nothing else.
    piped = subprocess.run(
        [sys.executable, "-m", "hbvs_cli", "repeat", str(FIT), *RUN_OPTIONS, "-o", "-", "--foxglove", str(free_port()), "--foxglove-speed", "0", "-q"],
        capture_output=True, timeout=120, env=env,
    )
    assert piped.returncode == 0 and piped.stdout == plain.read_bytes()


def test_live_view_says_what_is_wrong_in_one_line(tmp_path):
    port = free_port()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", port))
        taken.listen()
        result = subprocess.run(
            [sys.executable, "-m", "hbvs_cli", "repeat", str(FIT), *RUN_OPTIONS, "-o", str(tmp_path / "r.mcap"), "--foxglove", str(port)],
            capture_output=True, timeout=120,
        )
    assert result.returncode == 2 and not (tmp_path / "r.mcap").exists()
    # (the message names the option: --foxglove, or its former name in live_view's own words)
    assert len(result.stderr.decode().strip().splitlines()) == 1 and "--" in result.stderr.decode()


def test_without_the_sdk_the_error_says_what_to_install(monkeypatch):
    from hbvs_cli.errors import UsageError
    from hbvs_cli.io.live_view import live_writer

    monkeypatch.setitem(sys.modules, "foxglove", None)
    with pytest.raises(UsageError, match=r"pip install 'hbvs\[live\]'"):
        with live_writer(free_port()):
            pass
    with live_writer(None) as wrap:  # without --live the writer is the file's own
        assert wrap(wrap) is wrap


def test_foxglove_without_a_port_means_foxgloves_default():
    from hbvs_cli.cli.app import _live_port_given

    assert _live_port_given(["repeat", "f.mcap", "--foxglove", "--foxglove-speed", "0"]) == ["repeat", "f.mcap", "--foxglove", "8765", "--foxglove-speed", "0"]
    assert _live_port_given(["repeat", "f.mcap", "--foxglove"]) == ["repeat", "f.mcap", "--foxglove", "8765"]
    assert _live_port_given(["repeat", "f.mcap", "--foxglove", "9000"]) == ["repeat", "f.mcap", "--foxglove", "9000"]
    assert _live_port_given(["report", "run.mcap"]) == ["report", "run.mcap"]
    # --live alone now drives a robot: it is left as it is.
    assert _live_port_given(["repeat", "f.mcap", "--live"]) == ["repeat", "f.mcap", "--live"]
