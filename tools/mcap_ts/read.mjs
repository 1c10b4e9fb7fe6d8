// Reads MCAP files as Foxglove does, with the TypeScript reader @mcap/core, and prints what it found as one JSON
// object per file (one line each): every record streamed with CRCs validated, then every message through the
// indexed reader (Foxglove's way into a seekable file). Protobuf messages are decoded with their schema's own
// FileDescriptorSet, and those named foxglove.* a second time with Foxglove's own definitions (@foxglove/schemas,
// "foxglove" in the output); ROS 2 (cdr) messages with Foxglove's rosmsg parser and CDR reader; JSON messages parsed.
// A failure is reported in "error" rather than thrown.
// Usage: node tools/mcap_ts/read.mjs FILE.mcap...
import fs from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";
import { parse as parseRosMsg } from "@foxglove/rosmsg";
import { MessageReader as CdrMessageReader } from "@foxglove/rosmsg2-serialization";
import internal from "@foxglove/schemas/internal.js";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const handlers = await loadDecompressHandlers();
const foxgloveTypes = foxgloveRoot();

// Foxglove's message schemas as protobuf types, from the definitions @foxglove/schemas generates its .proto files from.
function foxgloveRoot() {
  const { foxgloveMessageSchemas, foxgloveEnumSchemas, generateProto } = internal;
  const root = new protobuf.Root();
  root.addJSON(protobuf.common["google/protobuf/timestamp.proto"].nested);
  root.addJSON(protobuf.common["google/protobuf/duration.proto"].nested);
  for (const schema of Object.values(foxgloveMessageSchemas)) {
    const enums = Object.values(foxgloveEnumSchemas).filter((e) => e.parentSchemaName === schema.name);
    protobuf.parse(generateProto(schema, enums), root, { keepCase: true });
  }
  root.resolveAll();
  return root;
}

const asObject = (type) => (data) => type.toObject(type.decode(data), { longs: Number });

function decoder(schemas, channel) {
  const schema = schemas.get(channel.schemaId);
  if (channel.messageEncoding === "json") return (data) => JSON.parse(new TextDecoder().decode(data));
  if (channel.messageEncoding === "cdr" && schema?.encoding === "ros2msg") {
    const reader = new CdrMessageReader(parseRosMsg(new TextDecoder().decode(schema.data), { ros2: true }));
    return (data) => reader.readMessage(data);
  }
  if (schema?.encoding !== "protobuf") return () => null;
  return asObject(protobuf.Root.fromDescriptor(descriptor.FileDescriptorSet.decode(schema.data)).lookupType(schema.name));
}

function foxgloveDecoder(schemas, channel) {
  const schema = schemas.get(channel.schemaId);
  if (schema?.encoding !== "protobuf" || !schema.name.startsWith("foxglove.")) return null;
  return asObject(foxgloveTypes.lookupType(schema.name));
}

function tally(counts, topic) {
  counts[topic] = (counts[topic] ?? 0) + 1;
}

async function streamed(path) {
  const reader = new McapStreamReader({ decompressHandlers: handlers, validateCrcs: true });
  reader.append(await fs.readFile(path));
  const schemas = new Map(), channels = new Map(), decoders = new Map(), counts = {}, first = {}, foxglove = {};
  let record;
  while ((record = reader.nextRecord())) {
    if (record.type === "Schema") schemas.set(record.id, record);
    else if (record.type === "Channel") channels.set(record.id, record);
    else if (record.type === "Message") {
      const channel = channels.get(record.channelId);
      if (!decoders.has(channel.id)) decoders.set(channel.id, [decoder(schemas, channel), foxgloveDecoder(schemas, channel)]);
      const [own, foxglove_own] = decoders.get(channel.id);
      tally(counts, channel.topic);
      first[channel.topic] ??= own(record.data);
      if (foxglove_own) foxglove[channel.topic] ??= foxglove_own(record.data);
    }
  }
  if (!reader.done()) throw new Error("the stream ended inside a record");
  return { counts, first, foxglove };
}

async function indexed(path) {
  const handle = await fs.open(path);
  try {
    const readable = {
      size: async () => BigInt((await handle.stat()).size),
      read: async (offset, length) => {
        const buffer = new Uint8Array(Number(length));
        await handle.read(buffer, 0, Number(length), Number(offset));
        return buffer;
      },
    };
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers: handlers });
    const counts = {};
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      tally(counts, reader.channelsById.get(message.channelId).topic);
    }
    let metadata = 0;
    for await (const _ of reader.readMetadata()) metadata++;
    return { counts, metadata, statistics: Number(reader.statistics?.messageCount ?? -1) };
  } finally {
    await handle.close();
  }
}

for (const path of process.argv.slice(2)) {
  const out = { path };
  for (const [name, read] of [["streamed", streamed], ["indexed", indexed]]) {
    try {
      out[name] = await read(path);
    } catch (error) {
      out[name] = { error: String(error.message ?? error) };
    }
  }
  console.log(JSON.stringify(out));
}
