"""Events (`/events`, foxglove.Event): labelled moments such as expert switches, written into a copy.

    add_events(trajectory_path, out_path, [Event(t_ns, {"kind": "expert_switch", "expert": "1"})])
    events = read_events(out_path)

The input file is never modified: the copy holds every record of the input plus the events, in time
order, so Foxglove and Rerun show them on the same timeline as the trajectory.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from mcap.records import Channel, Message, Schema

from cnep.recordings.constants import SCHEMA_EVENT, TOPIC_EVENTS
from cnep.recordings.container import read_mcap, refuse_overwrite_input, rewrite_mcap
from cnep.recordings.errors import RecordingError
from cnep.recordings.readers import in_file
from cnep.recordings.records import Event
from cnep.recordings.schemas import FOXGLOVE_CLASSES, decode_event, encode_event, schema_data


def add_events(src: str | os.PathLike, dst: str | os.PathLike, events: Sequence[Event]) -> Path:
    """Copy the MCAP file `src` to `dst` with `events` added on `/events` (appended if it exists).

    Returns `dst`. `src` must be a complete, valid file; `dst` is written atomically.
    """
    refuse_overwrite_input(src, dst)
    contents = read_mcap(src)
    contents = replace(
        contents,
        schemas=dict(contents.schemas),
        channels=dict(contents.channels),
        messages=list(contents.messages),
    )
    channel = contents.channel_of_topic(TOPIC_EVENTS)
    if channel is None:
        schema_id = max(contents.schemas, default=0) + 1
        contents.schemas[schema_id] = Schema(
            id=schema_id, name=SCHEMA_EVENT, encoding="protobuf", data=schema_data(FOXGLOVE_CLASSES[SCHEMA_EVENT])
        )
        channel = Channel(
            id=max(contents.channels, default=0) + 1,
            topic=TOPIC_EVENTS,
            message_encoding="protobuf",
            metadata={},
            schema_id=schema_id,
        )
        contents.channels[channel.id] = channel
    elif contents.schema_name(TOPIC_EVENTS) != SCHEMA_EVENT:
        raise RecordingError(
            f"{src}: topic {TOPIC_EVENTS} has schema {contents.schema_name(TOPIC_EVENTS)!r}, not {SCHEMA_EVENT!r}"
        )
    for e in events:
        contents.messages.append(
            Message(
                channel_id=channel.id,
                log_time=e.timestamp_ns,
                publish_time=e.timestamp_ns,
                sequence=0,
                data=encode_event(e),
            )
        )
    return rewrite_mcap(dst, contents)


def read_events(path: str | os.PathLike) -> list[Event]:
    """Events on `/events` of the file at `path`, in time order ([] if the file has none)."""
    contents = read_mcap(path)
    if contents.channel_of_topic(TOPIC_EVENTS) is None:
        return []
    with in_file(contents.path):
        events = [decode_event(m.data) for m in contents.topic_messages(TOPIC_EVENTS)]
    return sorted(events, key=lambda e: e.timestamp_ns)
