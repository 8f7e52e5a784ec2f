"""What an MCAP file holds, read in one pass (``hbvs info``): its kind, time span, settings and
topics; an hbvs file also gives its frames and target."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import InputError
from .mcap.reader import ChannelSummary, McapStream, read_metadata
from .topics import IMAGE_TOPIC, MODEL_TOPIC, RAW_DESIRED_TOPIC, ROUTE_SWITCHES_METADATA, ROUTE_TOPIC, STATE_TOPIC, STOPPED_METADATA

#: The topic with one message per frame (teach, fit) or per control step (run).
FRAME_TOPICS = {"teach": IMAGE_TOPIC, "fit": RAW_DESIRED_TOPIC, "run": STATE_TOPIC}


@dataclass
class FileInfo:
    """What :func:`read_file_info` found (``kind`` None for a file hbvs did not write)."""

    name: str
    kind: str | None = None
    version: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    metadata_names: list[str] = field(default_factory=list)
    topics: list[ChannelSummary] = field(default_factory=list)
    complete: bool = True
    stop_reason: str = ""
    target: str | None = None
    #: Why a live run stopped before its end (its ``hbvs.stopped`` record), else "".
    stopped: str = ""
    #: A route fit's segments: each one's first and last frame of the taught drive.
    segments: list[tuple[int, int]] = field(default_factory=list)
    #: A route run's switches: made and planned (run time, s).
    switches: list[float] = field(default_factory=list)
    planned_switches: list[float] = field(default_factory=list)

    @property
    def frames(self) -> int | None:
        """Frames (teach, fit; a route's: of the taught drive its segments cover) or control
        steps (run); None for a file hbvs did not write."""
        topic = FRAME_TOPICS.get(self.kind or "")
        if topic is None:
            return None
        if self.segments:  # in the drive's order
            return self.segments[-1][1] - self.segments[0][0] + 1
        return next((t.message_count for t in self.topics if t.topic == topic), 0)


def read_file_info(source: Any, name: str = "") -> FileInfo:
    """Read an MCAP file (a path, ``"-"`` for stdin, or a binary stream) through to its end."""

    if isinstance(source, (str, os.PathLike)) and str(source) != "-" and Path(source).is_dir():
        storage = sorted(Path(source).glob("*.mcap"))
        hint = f": give its storage file, e.g. {storage[0]}" if storage else ""
        raise InputError(f"{source}: is a folder, expected an MCAP file{hint}")
    stream = McapStream(source, name=name)
    target, segments = None, []
    for message in stream:
        if message.topic == MODEL_TOPIC and message.message_encoding == "json":  # a route's: one per segment
            kind_of_segment = message.json(stream.name).get("target_kind")
            target = kind_of_segment if target is None else f"{target} -> {kind_of_segment}"
        if message.topic == ROUTE_TOPIC and message.message_encoding == "json":
            route_record = message.json(stream.name)
            try:  # a route's segments as (first, last) frames; none if malformed (fit and repeat check it)
                segments = [(int(segment["first"]), int(segment["last"])) for segment in route_record["segments"]]
            except (KeyError, TypeError, ValueError):
                segments = []
    metadata = read_metadata(stream, "hbvs")
    kind = metadata.get("file_kind")
    settings = metadata.get("settings") if isinstance(metadata.get("settings"), dict) else {}
    route = metadata.get("route") if isinstance(metadata.get("route"), dict) else {}
    if target is None and list_of(route.get("target_kinds"), str):  # a route run's, in order
        target = " -> ".join(route["target_kinds"])
    if target is None:
        target = metadata.get("target_kind") or (settings.get("target") if kind == "teach" and metadata.get("source") == "sim" else None)
    return FileInfo(
        name=stream.name, kind=kind if kind in FRAME_TOPICS else None, version=metadata.get("hbvs_version"),
        metadata=metadata, metadata_names=sorted(stream.metadata), topics=list(stream.channels.values()),
        complete=not stream.truncated, stop_reason=stream.stop_reason,
        stopped=str(read_metadata(stream, STOPPED_METADATA).get("reason", "")),
        target=target if isinstance(target, str) else None, segments=segments,
        # info shows what it can of a malformed record (report refuses it: run_file.read_run)
        switches=list_of(read_metadata(stream, ROUTE_SWITCHES_METADATA).get("switch_times")) or [],
        planned_switches=list_of(route.get("switch_times")) or [],
    )


def list_of(values: Any, kind: type | tuple[type, ...] = (int, float)) -> list[Any] | None:
    """``values`` if a list of ``kind`` (bool is no number), else None (a malformed record)."""
    if isinstance(values, list) and all(isinstance(v, kind) and not isinstance(v, bool) for v in values):
        return values
    return None
