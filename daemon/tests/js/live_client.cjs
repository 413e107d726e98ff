#!/usr/bin/env node
// Independent client of metrolog's live view (docs/live-view.md): Foxglove's own WebSocket
// protocol client (npm @foxglove/ws-protocol, over the `ws` package) subscribes to every
// channel the daemon advertises and keeps every message it receives. The protobuf channels'
// advertised schemas are loaded with protobufjs and each of their messages decoded; the JSON
// channels' messages are parsed.
//
// Prints `subscribed <n>` on stdout once it has subscribed, then, when the server closes the
// connection (the run ended), one JSON line: the messages received (topic, log time in ns as a
// string, the bytes in base64) and the problems found.
//
// Usage: NODE_PATH=<npm dir>/node_modules node live_client.cjs ws://127.0.0.1:PORT

"use strict";
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

const url = process.argv[2];
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const bySub = new Map();
const received = [];
const problems = [];
let serverName = null;

function decoderOf(channel) {
  if (channel.encoding === "json") {
    const text = new TextDecoder();
    return (bytes) => JSON.parse(text.decode(bytes));
  }
  if (channel.encoding === "protobuf" && channel.schemaEncoding === "protobuf") {
    const set = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
    const type = protobuf.Root.fromDescriptor(set).lookupType(channel.schemaName);
    return (bytes) => type.decode(bytes);
  }
  throw new Error(`${channel.topic}: encoding ${channel.encoding} / ${channel.schemaEncoding}`);
}

client.on("serverInfo", (info) => {
  serverName = info.name;
  if (info.capabilities.length > 0) problems.push(`capabilities ${info.capabilities}`);
});

client.on("advertise", (channels) => {
  for (const c of channels) {
    try {
      const decode = decoderOf(c);
      bySub.set(client.subscribe(c.id), { topic: c.topic, decode });
    } catch (e) {
      problems.push(`cannot load the schema of ${c.topic}: ${e.message}`);
    }
  }
  process.stdout.write(`subscribed ${bySub.size}\n`);
});

client.on("message", ({ subscriptionId, timestamp, data }) => {
  const sub = bySub.get(subscriptionId);
  if (!sub) {
    problems.push(`message for unknown subscription ${subscriptionId}`);
    return;
  }
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  try {
    sub.decode(bytes);
  } catch (e) {
    problems.push(`${sub.topic}: does not decode: ${e.message}`);
  }
  received.push({
    topic: sub.topic,
    log_ns: timestamp.toString(),
    data: Buffer.from(bytes).toString("base64"),
  });
});

client.on("error", (e) => problems.push(`client error: ${e && e.message ? e.message : e}`));

client.on("close", () => {
  // Exit once the pipe has it all (stdout to a pipe is asynchronous in node).
  const out = JSON.stringify({ server: serverName, received, problems }) + "\n";
  process.stdout.write(out, () => process.exit(0));
});
