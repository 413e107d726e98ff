#!/usr/bin/env python3
"""Independent reader of a metrolog MCAP log (the `mcap`, `jsonschema` and `protobuf` pip
packages).

Reads the file record by record (so the intact prefix of a log whose writer was killed is
read too), validates every JSON message against the JSON schema of its channel, decodes every
protobuf batch of the raw topics with the FileDescriptorSet of its channel (counts are then
samples, not messages; docs/log-format.md), and prints one JSON summary on stdout:

  complete      footer and closing magic present (the writer closed the file)
  read_error    why reading stopped early (a truncated file), or null
  counts        messages per topic
  errors        schema violations (first 20) and n_errors
  poses         every /pose message
  last_status   the last /status message
  attachments   attachment names
  metadata      metadata records by name
  first_ns, last_ns   log times of the first and last message

Usage: read_log.py LOG.mcap
"""
import json
import sys

from jsonschema import validators
from mcap.records import Attachment, Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader


def protobuf_samples(schema, data, classes):
    """Samples in one raw batch, decoded with the channel's own FileDescriptorSet."""
    cls = classes.get(schema.id)
    if cls is None:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

        pool = descriptor_pool.DescriptorPool()
        for fd in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
            pool.Add(fd)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
        classes[schema.id] = cls
    header = cls.FromString(data).header
    # Format 3 says how many samples a batch holds; format 2 has one seq per sample.
    count = getattr(header, "count", None)
    return count if count is not None else len(header.seq)


def main(path):
    classes = {}
    schemas, channels, validators_by_schema = {}, {}, {}
    counts, errors, poses = {}, [], []
    attachments, metadata = [], {}
    last_status, first_ns, last_ns = None, None, None
    complete, read_error = False, None
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False, emit_chunks=False).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Message):
                    ch = channels[rec.channel_id]
                    schema = schemas[ch.schema_id]
                    if schema.encoding == "protobuf" and ch.message_encoding == "protobuf":
                        n = protobuf_samples(schema, rec.data, classes)
                        counts[ch.topic] = counts.get(ch.topic, 0) + n
                        continue
                    if schema.encoding != "jsonschema" or ch.message_encoding != "json":
                        errors.append(f"{ch.topic}: encoding {schema.encoding}/{ch.message_encoding}")
                        continue
                    v = validators_by_schema.get(schema.id)
                    if v is None:
                        doc = json.loads(schema.data)
                        cls = validators.validator_for(doc)
                        cls.check_schema(doc)
                        v = validators_by_schema[schema.id] = cls(doc)
                    msg = json.loads(rec.data)
                    for e in v.iter_errors(msg):
                        errors.append(f"{ch.topic} @ {rec.log_time}: {e.message}")
                    counts[ch.topic] = counts.get(ch.topic, 0) + 1
                    first_ns = rec.log_time if first_ns is None else min(first_ns, rec.log_time)
                    last_ns = rec.log_time if last_ns is None else max(last_ns, rec.log_time)
                    if ch.topic == "/pose":
                        poses.append(msg)
                    elif ch.topic == "/status":
                        last_status = msg
                elif isinstance(rec, Attachment):
                    attachments.append(rec.name)
                elif isinstance(rec, Metadata):
                    metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Footer):
                    complete = True
        except Exception as e:  # a truncated or damaged tail: keep what was read
            read_error = f"{type(e).__name__}: {e}"
            complete = False
    print(json.dumps({
        "complete": complete,
        "read_error": read_error,
        "counts": counts,
        "errors": errors[:20],
        "n_errors": len(errors),
        "poses": poses,
        "last_status": last_status,
        "attachments": attachments,
        "metadata": metadata,
        "first_ns": first_ns,
        "last_ns": last_ns,
    }))


if __name__ == "__main__":
    main(sys.argv[1])
