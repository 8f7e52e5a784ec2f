"""The channel list of an MCAP file from its summary section, read cheaply under the same caps."""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass

from ...errors import InputError
from .caps import MAX_RECORD_BYTES
from .reader import _CappedInput, _Declarations, _FieldTooLarge


@dataclass(frozen=True)
class ChannelSummary:
    """One channel as an MCAP file's summary section lists it.

    Attributes
    ----------
    topic, schema_name, schema_encoding, message_encoding : str
    message_count : int or None
        From the statistics record; None when the file has none.
    """

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    message_count: int | None


def read_summary(path: str | os.PathLike[str], name: str = "") -> list[ChannelSummary] | None:
    """The channels listed in the summary section of an MCAP file, read under the caps.

    Only the footer and the summary section are read (by the mcap library's seeking
    reader, through the same capped input), so this is cheap on a large file.

    Returns
    -------
    list of ChannelSummary, or None
        None when the file has no usable summary (a crashed writer never wrote one, or it
        is damaged): stream the file with :class:`McapStream` instead.

    Raises
    ------
    InputError
        The file cannot be read.
    RecordingError
        The summary declares more than the caps allow.
    """
    from mcap.exceptions import McapError
    from mcap.reader import SeekingReader

    name = name or str(path)
    declarations = _Declarations(name)
    try:
        with open(path, "rb") as stream:
            summary = SeekingReader(_CappedInput(stream), record_size_limit=MAX_RECORD_BYTES).get_summary()
    except OSError as exc:
        raise InputError(f"{name}: cannot read ({exc.strerror or exc})") from None
    except (McapError, _FieldTooLarge, ValueError, struct.error, UnicodeDecodeError, OverflowError, EOFError, KeyError):
        return None
    if summary is None or not summary.channels:
        return None
    for schema in summary.schemas.values():
        declarations.add_schema(schema)
    for channel in summary.channels.values():
        declarations.add_channel(channel)
    counts = dict(summary.statistics.channel_message_counts) if summary.statistics is not None else None
    listed = []
    for channel_id, channel in declarations.channels.items():
        schema = declarations.schemas.get(channel.schema_id)
        listed.append(ChannelSummary(
            topic=channel.topic,
            schema_name=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            message_encoding=channel.message_encoding,
            message_count=counts.get(channel_id, 0) if counts is not None else None,
        ))
    return listed
