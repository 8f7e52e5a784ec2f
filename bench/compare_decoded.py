"""Compare the decoded content of two hbvs files written before and after the switch of
``foxglove.*`` messages from JSON to protobuf (issue 27): every message on every topic, in
order, with its log time; foxglove messages compared as protobuf (a JSON one converted
field by field), ``hbvs.*`` messages byte for byte, metadata records as decoded values.

    python bench/compare_decoded.py OLD.mcap NEW.mcap

Prints one line per topic (and per metadata entry that differs); exits 1 on any difference.
"""

from __future__ import annotations

import base64
import importlib
import json
import os
import sys

from google.protobuf.message_factory import GetMessageClass
from mcap.reader import make_reader


def foxglove_class(schema_name: str):
    name = schema_name.split(".", 1)[1]
    return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)


def from_json(message_class, value: dict):
    """A protobuf message from Foxglove's JSON form ({"sec", "nsec"} times, base64 bytes)."""
    message = message_class()
    for field in message_class.DESCRIPTOR.fields:
        if field.name not in value:
            continue
        item = value[field.name]
        sub = field.message_type
        repeated = field.is_repeated
        if sub is not None and sub.full_name in ("google.protobuf.Timestamp", "google.protobuf.Duration"):
            getattr(message, field.name).seconds = item["sec"]
            getattr(message, field.name).nanos = item["nsec"]
        elif sub is not None:
            sub_class = GetMessageClass(sub)
            if repeated:
                for element in item:
                    getattr(message, field.name).add().CopyFrom(from_json(sub_class, element))
            else:
                getattr(message, field.name).CopyFrom(from_json(sub_class, item))
        elif field.type == field.TYPE_BYTES:
            setattr(message, field.name, base64.b64decode(item))
        elif repeated:
            getattr(message, field.name).extend(item)
        else:
            setattr(message, field.name, item)
    return message


def canonical(path: str):
    with open(path, "rb") as handle:
        reader = make_reader(handle)
        # Input paths name the file's own folder: compared without it.
        folder = os.path.dirname(os.path.abspath(path))
        metadata = {m.name: {k: v.replace(folder, "<folder>") for k, v in m.metadata.items()} for m in reader.iter_metadata()}
        messages = []
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema.name.startswith("foxglove."):
                cls = foxglove_class(schema.name)
                decoded = from_json(cls, json.loads(message.data)) if channel.message_encoding == "json" else cls.FromString(message.data)
                data = decoded.SerializeToString(deterministic=True)
            else:
                data = message.data
            messages.append((channel.topic, schema.name, message.log_time, data))
    return metadata, messages


def main(old: str, new: str) -> int:
    old_meta, old_messages = canonical(old)
    new_meta, new_messages = canonical(new)
    differs = 0
    for name in sorted(set(old_meta) | set(new_meta)):
        for key in sorted(set(old_meta.get(name, {})) | set(new_meta.get(name, {}))):
            if old_meta.get(name, {}).get(key) != new_meta.get(name, {}).get(key):
                print(f"metadata {name}.{key} differs")
                differs = 1
    topics = sorted({m[0] for m in old_messages} | {m[0] for m in new_messages})
    for topic in topics:
        a = [m for m in old_messages if m[0] == topic]
        b = [m for m in new_messages if m[0] == topic]
        if a != b:
            first = next((k for k, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
            print(f"{topic}: differs ({len(a)} vs {len(b)} messages; first difference at message {first})")
            differs = 1
        else:
            print(f"{topic}: {len(a)} messages identical")
    print(f"{old} and {new}: {'different' if differs else 'the same content'}")
    return differs


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
