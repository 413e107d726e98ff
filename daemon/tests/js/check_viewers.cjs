#!/usr/bin/env node
// Independent check that every channel of a metrolog log opens in Foxglove / Lichtblick
// (docs/log-format.md). It reads the log with the viewers' own MCAP reader (npm @mcap/core,
// zstd from @mcap/support) and applies the rules the viewers document and implement:
//
// - JSON channels (`jsonschema` schema, `json` messages): the schema's root is an object with
//   `properties`; no `$ref` anywhere; every field has one scalar `type` string among
//   boolean/string/number/integer/object/array; an object field has `properties`; an array has
//   one `items` schema of one of those types; a string's `contentEncoding` is absent or base64.
//   Every message parses as JSON and holds no number beyond 2^53 (JavaScript rounds it).
// - protobuf channels: the schema data is a FileDescriptorSet that protobufjs loads, the
//   schema name resolves to a message type, and every message decodes with it.
//
// Prints one JSON summary on stdout: per topic the channel's encodings, the message count,
// the first message decoded (64-bit integers as strings), and the problems found.
//
// Usage: NODE_PATH=<npm dir>/node_modules node check_viewers.cjs LOG.mcap

"use strict";
const fs = require("fs");
const { McapStreamReader } = require("@mcap/core");
const { loadDecompressHandlers } = require("@mcap/support");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

const SCALARS = new Set(["boolean", "string", "number", "integer", "object", "array"]);

function hasRef(v) {
  if (Array.isArray(v)) return v.some(hasRef);
  if (v && typeof v === "object") {
    return Object.entries(v).some(([k, x]) => k === "$ref" || hasRef(x));
  }
  return false;
}

// Problems of an object schema at `path` (empty: a viewer loads it).
function checkObject(schema, path, out) {
  if (schema.type !== "object") {
    out.push(`${path}: type ${JSON.stringify(schema.type)}, not "object"`);
    return;
  }
  if (!schema.properties || typeof schema.properties !== "object") {
    out.push(`${path}: an object without properties`);
    return;
  }
  for (const [name, f] of Object.entries(schema.properties)) {
    checkField(f, `${path}.${name}`, out);
  }
}

function checkField(f, path, out) {
  if (typeof f.type !== "string" || !SCALARS.has(f.type)) {
    out.push(`${path}: type ${JSON.stringify(f.type)} is not one scalar type`);
    return;
  }
  if (f.type === "string" && f.contentEncoding !== undefined && f.contentEncoding !== "base64") {
    out.push(`${path}: contentEncoding ${f.contentEncoding}`);
  }
  if (f.type === "object") checkObject(f, path, out);
  if (f.type === "array") {
    const it = f.items;
    if (!it || Array.isArray(it) || typeof it.type !== "string" || !SCALARS.has(it.type) || it.type === "array") {
      out.push(`${path}: array items ${JSON.stringify(it)} are not one item type`);
    } else if (it.type === "object") {
      checkObject(it, `${path}[]`, out);
    } else if (it.type === "string" && it.contentEncoding !== undefined) {
      out.push(`${path}[]: contentEncoding on array items`);
    }
  }
}

function unsafeNumbers(v, path, out) {
  if (typeof v === "number" && Math.abs(v) > Number.MAX_SAFE_INTEGER) out.push(path);
  else if (Array.isArray(v)) v.forEach((x, i) => unsafeNumbers(x, `${path}[${i}]`, out));
  else if (v && typeof v === "object") {
    for (const [k, x] of Object.entries(v)) unsafeNumbers(x, `${path}.${k}`, out);
  }
}

async function main(file) {
  const decompressHandlers = await loadDecompressHandlers();
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(fs.readFileSync(file));
  const schemas = new Map();
  const channels = new Map();
  const topics = {};
  let footer = false;
  for (let rec; (rec = reader.nextRecord()); ) {
    if (rec.type === "Schema") schemas.set(rec.id, rec);
    else if (rec.type === "Footer") footer = true;
    else if (rec.type === "Channel") {
      if (channels.has(rec.id)) continue;
      const schema = schemas.get(rec.schemaId);
      const t = (topics[rec.topic] = {
        message_encoding: rec.messageEncoding,
        schema_encoding: schema ? schema.encoding : null,
        schema_name: schema ? schema.name : null,
        messages: 0,
        samples: 0,
        first: null,
        problems: [],
      });
      const ch = { topic: t, decode: null };
      channels.set(rec.id, ch);
      if (!schema) {
        t.problems.push("no schema");
      } else if (schema.encoding === "jsonschema" && rec.messageEncoding === "json") {
        const doc = JSON.parse(Buffer.from(schema.data).toString("utf8"));
        if (hasRef(doc)) t.problems.push("the schema uses $ref");
        checkObject(doc, schema.name, t.problems);
        ch.decode = (data) => JSON.parse(Buffer.from(data).toString("utf8"));
      } else if (schema.encoding === "protobuf" && rec.messageEncoding === "protobuf") {
        try {
          const set = descriptor.FileDescriptorSet.decode(schema.data);
          const root = protobuf.Root.fromDescriptor(set);
          const type = root.lookupType(schema.name);
          ch.decode = (data) =>
            type.toObject(type.decode(data), { longs: String, defaults: true, arrays: true });
        } catch (e) {
          t.problems.push(`protobuf descriptors do not load: ${e.message}`);
        }
      } else {
        t.problems.push(`unsupported encodings ${schema.encoding}/${rec.messageEncoding}`);
      }
    } else if (rec.type === "Message") {
      const ch = channels.get(rec.channelId);
      const t = ch.topic;
      t.messages += 1;
      if (!ch.decode) continue;
      let msg;
      try {
        msg = ch.decode(rec.data);
      } catch (e) {
        if (t.problems.length < 20) t.problems.push(`message ${t.messages} does not decode: ${e.message}`);
        continue;
      }
      if (t.message_encoding === "json") {
        const bad = [];
        unsafeNumbers(msg, "", bad);
        if (bad.length && t.problems.length < 20) {
          t.problems.push(`numbers beyond 2^53 at ${bad.slice(0, 3).join(", ")}`);
        }
      } else if (msg.header) {
        // Format 3 says how many samples a batch holds; format 2 has one seq per sample.
        t.samples += msg.header.count !== undefined ? msg.header.count : msg.header.seq.length;
      }
      if (t.first === null) t.first = msg;
    }
  }
  process.stdout.write(JSON.stringify({ footer, topics }));
}

main(process.argv[2]).catch((e) => {
  process.stderr.write(`check_viewers: ${e.stack || e}\n`);
  process.exit(1);
});
