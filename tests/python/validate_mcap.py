"""Independent check of an MCAP file written by magcomp.

Reads the file with the official Python `mcap` reader and decodes every
message with `mcap-protobuf-support`, using only the descriptors embedded
in the file. Prints a JSON summary on stdout: message count per topic,
the schema names, the first decoded value of chosen fields, metadata and
attachment names. Exits non-zero if any message fails to decode.

Usage: python validate_mcap.py FILE.mcap
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main(path: str) -> int:
    counts: dict[str, int] = {}
    schemas: dict[str, str] = {}
    first: dict[str, dict[str, float]] = {}
    last_log_time: dict[str, int] = {}
    timestamps_match = True
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            schemas[topic] = schema.name
            stamp = decoded.timestamp.seconds * 1_000_000_000 + decoded.timestamp.nanos
            timestamps_match &= stamp == message.log_time
            last_log_time[topic] = message.log_time
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
