// Reads MCAP files as Foxglove does, with the TypeScript reader @mcap/core, and prints what it found as one JSON
// object per file (one line each): every record streamed with CRCs validated, then every message through the
// indexed reader (Foxglove's way into a seekable file). Protobuf messages are decoded with their schema's own
// FileDescriptorSet and JSON messages parsed; a failure is reported in "error" rather than thrown.
// Usage: node tools/mcap_ts/read.mjs FILE.mcap...
import fs from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const handlers = await loadDecompressHandlers();

function decoder(schemas, channel) {
  const schema = schemas.get(channel.schemaId);
  if (channel.messageEncoding === "json") return (data) => JSON.parse(new TextDecoder().decode(data));
  if (schema?.encoding !== "protobuf") return () => null;
  const type = protobuf.Root.fromDescriptor(descriptor.FileDescriptorSet.decode(schema.data)).lookupType(schema.name);
  return (data) => type.toObject(type.decode(data), { longs: Number });
}

function tally(counts, topic) {
  counts[topic] = (counts[topic] ?? 0) + 1;
}

async function streamed(path) {
  const reader = new McapStreamReader({ decompressHandlers: handlers, validateCrcs: true });
  reader.append(await fs.readFile(path));
  const schemas = new Map(), channels = new Map(), decoders = new Map(), counts = {}, first = {};
  let record;
  while ((record = reader.nextRecord())) {
    if (record.type === "Schema") schemas.set(record.id, record);
    else if (record.type === "Channel") channels.set(record.id, record);
    else if (record.type === "Message") {
      const channel = channels.get(record.channelId);
      if (!decoders.has(channel.id)) decoders.set(channel.id, decoder(schemas, channel));
      const message = decoders.get(channel.id)(record.data);
      tally(counts, channel.topic);
      first[channel.topic] ??= message;
    }
  }
  if (!reader.done()) throw new Error("the stream ended inside a record");
  return { counts, first };
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
