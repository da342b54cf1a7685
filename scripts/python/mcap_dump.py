"""Prints every transition of a JSAE-RL recording as one JSON line, decoded by the `mcap`
reader and its protobuf decoder from the schema inside the file (no JSAE-RL code involved).

Usage: mcap_dump.py FILE.mcap
The first line is the channel: {"topic", "schema", "message_encoding", "metadata"}.
"""

import json
import sys

from google.protobuf.json_format import MessageToDict
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main(path):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        first = True
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            if first:
                print(json.dumps({
                    "topic": channel.topic,
                    "schema": schema.name,
                    "message_encoding": channel.message_encoding,
                    "metadata": dict(channel.metadata),
                }))
                first = False
            row = MessageToDict(
                decoded,
                preserving_proto_field_name=True,
                always_print_fields_with_no_presence=True,
            )
            row["sequence"] = message.sequence
            print(json.dumps(row))


if __name__ == "__main__":
    main(sys.argv[1])
