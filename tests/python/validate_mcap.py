"""Independent check of an MCAP file written by magcomp.

Reads the file with the official Python `mcap` reader and decodes every
message with `mcap-protobuf-support` (protobuf, from the descriptors
embedded in the file) or `mcap-ros2-support` (ROS 2 CDR, from the ros2msg
schema text in the file). Prints a JSON summary on stdout: message count per topic,
the schema names, the first decoded value of chosen fields, metadata and
attachment names. Exits non-zero if any message fails to decode.

Usage: python validate_mcap.py FILE.mcap
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory


def numeric_fields(message, prefix=""):
    """Numeric fields of a decoded ROS 2 message, flattened as a.b.c."""
    out = {}
    names = getattr(message, "__slots__", None) or list(vars(message))
    for name in names:
        value = getattr(message, name)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            out[prefix + name] = float(value)
        elif hasattr(value, "__slots__") or hasattr(value, "__dict__"):
            out.update(numeric_fields(value, prefix + name + "."))
    return out


def main(path: str) -> int:
    counts: dict[str, int] = {}
    schemas: dict[str, str] = {}
    first: dict[str, dict[str, float]] = {}
    last_log_time: dict[str, int] = {}
    timestamps_match = True
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory(), Ros2DecoderFactory()])
        summary = reader.get_summary()
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            schemas[topic] = schema.name
            last_log_time[topic] = message.log_time
            if channel.message_encoding == "cdr":
                stamp = decoded.header.stamp.sec * 1_000_000_000 + decoded.header.stamp.nanosec
                timestamps_match &= stamp == message.log_time
                first.setdefault(topic, numeric_fields(decoded))
                continue
            stamp = decoded.timestamp.seconds * 1_000_000_000 + decoded.timestamp.nanos
            timestamps_match &= stamp == message.log_time
            if topic not in first:
                first[topic] = {
                    field.name: value
                    for field, value in decoded.ListFields()
                    if isinstance(value, float)
                }
        stream.seek(0)
        reader = make_reader(stream)
        metadata = sorted(record.name for record in reader.iter_metadata())
        attachments = sorted(record.name for record in reader.iter_attachments())
    result = {
        "counts": counts,
        "schemas": schemas,
        "first": first,
        "timestamps_match_log_time": timestamps_match,
        "chunk_indexes": len(summary.chunk_indexes) if summary else 0,
        "metadata": metadata,
        "attachments": attachments,
    }
    json.dump(result, sys.stdout, indent=1, sort_keys=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
