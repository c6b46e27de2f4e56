"""Reads a flight record with the MCAP project's Python reader, as a script or a viewer outside
cabletrack would: its channels and schemas, every message decoded (JSON messages with `json`,
protobuf ones from the schema the file carries, with `mcap-protobuf-support`), and every JSON
message checked against its channel's JSON Schema by an independent validator (`jsonschema`).

    read_with_mcap.py RECORD.mcap OUT.json

OUT.json: {"channels": {topic: {...}}, "messages": {topic: [decoded, ...]},
"invalid": [why, ...], "validated": N, "tampered_rejected": bool}
"""

import json
import sys

import jsonschema
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def protobuf_summary(schema_name, message):
    if schema_name == "foxglove.RawImage":
        return {
            "timestamp": [message.timestamp.seconds, message.timestamp.nanos],
            "frame_id": message.frame_id,
            "width": message.width,
            "height": message.height,
            "encoding": message.encoding,
            "step": message.step,
            "data": list(message.data),
        }
    if schema_name == "foxglove.ImageAnnotations":
        return {
            "timestamps": [[p.timestamp.seconds, p.timestamp.nanos] for p in message.points],
            "points": [len(p.points) for p in message.points],
            "texts": [t.text for t in message.texts],
        }
    if schema_name == "foxglove.CompressedVideo":
        return {
            "timestamp": [message.timestamp.seconds, message.timestamp.nanos],
            "frame_id": message.frame_id,
            "format": message.format,
            "data_hex": message.data.hex(),
        }
    raise SystemExit(f"unexpected protobuf schema {schema_name}")


def main(record, out):
    channels, messages, invalid = {}, {}, []
    validators, validated, tampered_rejected = {}, 0, None
    with open(record, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        protobuf = DecoderFactory()
        summary = reader.get_summary()
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            channels[channel.topic] = {
                "message_encoding": channel.message_encoding,
                "schema_name": schema.name,
                "schema_encoding": schema.encoding,
                "count": summary.statistics.channel_message_counts[channel.id],
            }
            if schema.encoding == "jsonschema":
                document = json.loads(schema.data)
                jsonschema.Draft202012Validator.check_schema(document)
                validators[channel.topic] = jsonschema.Draft202012Validator(document)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.message_encoding == "json":
                value = json.loads(message.data)
                for error in validators[channel.topic].iter_errors(value):
                    invalid.append(f"{channel.topic} at {message.log_time}: {error.message}")
                validated += 1
                if tampered_rejected is None and "stamp" in value:
                    # A validator that accepts anything would make the check above say nothing.
                    tampered = dict(value, stamp=dict(value["stamp"], seq="not a number"))
                    tampered_rejected = not validators[channel.topic].is_valid(tampered)
            else:
                decode = protobuf.decoder_for(channel.message_encoding, schema)
                if decode is None:
                    raise SystemExit(f"{channel.topic}: no decoder for {channel.message_encoding}")
                value = protobuf_summary(schema.name, decode(message.data))
            messages.setdefault(channel.topic, []).append(
                {"log_time": message.log_time, "value": value}
            )
    with open(out, "w") as f:
        json.dump(
            {
                "channels": channels,
                "messages": messages,
                "invalid": invalid,
                "validated": validated,
                "tampered_rejected": bool(tampered_rejected),
            },
            f,
        )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
