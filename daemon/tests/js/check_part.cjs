#!/usr/bin/env node
// Opens one MCAP file the way Foxglove / Lichtblick open a local file: @mcap/core's
// McapIndexedReader (summary section, chunk indexes, then the chunks through the index), zstd
// from @mcap/support. Used on each part of a split run (daemon/tests/log_viewers.rs): a part
// must stand alone.
//
// Prints JSON: messages read through the index per topic, the statistics' message count,
// attachment and metadata names (from the summary's indexes), and the run metadata's keys.
//
// Usage: NODE_PATH=<npm dir>/node_modules node check_part.cjs PART.mcap

"use strict";
const fs = require("fs");
const { McapIndexedReader } = require("@mcap/core");
const { loadDecompressHandlers } = require("@mcap/support");

async function main(file) {
  const fd = fs.openSync(file, "r");
  const size = BigInt(fs.fstatSync(fd).size);
  const readable = {
    size: async () => size,
    read: async (offset, length) => {
      const buf = Buffer.alloc(Number(length));
      fs.readSync(fd, buf, 0, Number(length), Number(offset));
      return buf;
    },
  };
  const decompressHandlers = await loadDecompressHandlers();
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const topics = {};
  for await (const m of reader.readMessages()) {
    const t = reader.channelsById.get(m.channelId).topic;
    topics[t] = (topics[t] || 0) + 1;
  }
  const run = [];
  for await (const m of reader.readMetadata({ name: "metrolog.run" })) {
    run.push(Object.fromEntries(m.metadata));
  }
  const out = {
    chunks: reader.chunkIndexes.length,
    channels: reader.channelsById.size,
    statistics_messages: reader.statistics ? Number(reader.statistics.messageCount) : null,
    topics,
    attachments: reader.attachmentIndexes.map((a) => a.name),
    metadata: reader.metadataIndexes.map((m) => m.name),
    run,
  };
  process.stdout.write(JSON.stringify(out));
}

main(process.argv[2]).catch((e) => {
  process.stderr.write(String(e && e.stack ? e.stack : e));
  process.exit(1);
});
