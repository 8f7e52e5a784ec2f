"""``hbvs info``: what a teach, fit or run file holds (see :mod:`hbvs_cli.io.file_info`)."""

from __future__ import annotations

import json
import shutil
import textwrap
from datetime import datetime, timezone
from typing import Any, TextIO

from ..settings.commands import InfoOptions
from .console import Console, print_document


def info_document(info: Any) -> dict[str, Any]:
    """The file's description as one JSON-ready object (the keys of ``hbvs info --json``); its time
    span (ns) is its messages' log times'."""
    start = min((topic.first_ns for topic in info.topics), default=None)
    end = max((topic.last_ns for topic in info.topics), default=None)
    return {
        "file": info.name, "kind": info.kind, "hbvs_version": info.version,
        "complete": info.complete, "stop_reason": info.stop_reason or None, "stopped": info.stopped or None,
        "start_ns": start, "end_ns": end, "duration_s": 0.0 if start is None else round((end - start) * 1e-9, 9),
        "frames": info.frames, "messages": sum(topic.message_count for topic in info.topics), "target": info.target,
        **({"segments": [list(frames) for frames in info.segments]} if info.segments else {}),
        **({"switch_times": info.switches, "planned_switch_times": info.planned_switches} if info.planned_switches else {}),
        "settings": info.metadata.get("settings"),
        "metadata": {key: value for key, value in info.metadata.items() if key != "settings"},
        "metadata_records": info.metadata_names,
        "topics": [{"topic": topic.topic, "messages": topic.message_count, "schema": topic.schema_name,
                    "schema_encoding": topic.schema_encoding, "message_encoding": topic.message_encoding} for topic in info.topics],
    }


def _stamp(ns: int | None) -> str:
    if ns is None:
        return "-"
    when = datetime.fromtimestamp(ns // 1_000_000_000, tz=timezone.utc).replace(microsecond=(ns % 1_000_000_000) // 1000)
    return when.isoformat(timespec="milliseconds").replace("+00:00", "Z")


#: Significant digits of a number shown by ``hbvs info`` (``--json`` keeps every digit).
SHOWN_DIGITS = 6


def _rounded(value: Any) -> Any:
    """``value`` with each float rounded to :data:`SHOWN_DIGITS` significant digits (30.000000299999996 Hz reads 30)."""
    if isinstance(value, float):
        shown = float(f"{value:.{SHOWN_DIGITS}g}")
        return int(shown) if shown.is_integer() and abs(shown) < 1e15 else shown
    if isinstance(value, dict):
        return {key: _rounded(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_rounded(item) for item in value]
    return value


def _value(value: Any) -> str:
    # A space after each comma: a long value wraps between its items, never inside a number.
    return value if isinstance(value, str) else json.dumps(_rounded(value), separators=(", ", ":"))


def print_info(document: dict[str, Any], out: TextIO, width: int = 100) -> None:
    """The description as aligned lines, wrapped to ``width`` columns."""
    kind = document["kind"] or "not an hbvs file"
    if document["hbvs_version"]:
        kind += f" (hbvs {document['hbvs_version']})"
    rows = [
        ("file", document["file"]),
        ("kind", kind),
        ("complete", "yes" if document["complete"] else f"no: {document['stop_reason']}"),
        *([("stopped", f"before its end: {document['stopped']}")] if document["stopped"] else []),
        ("duration", f"{document['duration_s']:.3f} s"),
        ("start", _stamp(document["start_ns"])),
        ("end", _stamp(document["end_ns"])),
        ("messages", str(document["messages"])),
    ]
    if document["frames"] is not None:
        rows.append(("steps" if document["kind"] == "run" else "frames", str(document["frames"])))
    if document.get("segments"):
        rows.append(("segments", f"{len(document['segments'])}: frames " + ", ".join(f"{first}-{last}" for first, last in document["segments"])))
    if document["target"]:
        rows.append(("target", document["target"]))
    if document.get("planned_switch_times"):
        made = ", ".join(f"{t:.2f}" for t in document["switch_times"]) or "none"
        rows.append(("switches", f"at {made} s (planned {', '.join(f'{t:.2f}' for t in document['planned_switch_times'])} s)"))
    for key in ("source", "mode", "law", "input"):
        if key in document["metadata"]:
            rows.append((key, _value(document["metadata"][key])))
    settings = document["settings"] or {}
    shown = [f"{key}={_value(value)}" for key, value in settings.items() if value is not None and value is not False]
    if shown:
        rows.append(("settings", " ".join(shown)))
    label_width = max(len(label) for label, _ in rows) + 2
    for label, text in rows:
        # Only a word longer than the room (a path) is folded over lines.
        lines = textwrap.wrap(text, max(20, width - label_width), break_on_hyphens=False) or [""]
        out.write(f"{label:<{label_width}}{lines[0]}\n")
        for line in lines[1:]:
            out.write(" " * label_width + line + "\n")
    topics = document["topics"]
    out.write(f"topics{' ' * (label_width - 6)}{len(topics)}\n")
    name_width = max((len(t["topic"]) for t in topics), default=0)
    count_width = max((len(str(t["messages"])) for t in topics), default=0)
    for topic in topics:
        line = (f"  {topic['topic']:<{name_width}}  {topic['messages']:>{count_width}} msgs  "
                f"{topic['schema'] or '(no schema)'} [{topic['schema_encoding'] or topic['message_encoding']}]")
        # Too wide: the schema goes under the topic, indented, rather than past the width.
        lines = textwrap.wrap(line, max(20, width), subsequent_indent=" " * 6, break_on_hyphens=False, break_long_words=False)
        out.write("\n".join([line] if len(line) <= width else ["  " + lines[0].lstrip(), *lines[1:]]) + "\n")


def run_info(options: InfoOptions, console: Console) -> None:
    """Read the file and print its description on stdout (text or ``--json``)."""
    from ..io.file_info import read_file_info

    info = read_file_info(options.input)
    if not info.complete:
        console.warn(f"{info.name}: read up to {info.stop_reason.split(' (')[0]}; the rest is lost")
    document = info_document(info)
    print_document(document, options.json_output, lambda _, out: print_info(document, out, width=shutil.get_terminal_size((100, 24)).columns))
