// Reads an MCAP file as Foxglove does: @mcap/core's indexed reader (zstd chunks via fzstd), each
// protobuf channel decoded with protobufjs from the FileDescriptorSet stored as its schema.
// Usage: node read_mcap.mjs FILE.mcap [TOPIC ...]; prints {topic: {schema, count, first, children}} as JSON
// (children: message count per child_frame_id, for FrameTransform topics).
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { decompress } from "fzstd";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const [file, ...topics] = process.argv.slice(2);
const handle = await open(file, "r");
const readable = {
  size: async () => BigInt((await handle.stat()).size),
  read: async (offset, length) => {
    const buf = new Uint8Array(Number(length));
    await handle.read(buf, 0, Number(length), Number(offset));
    return buf;
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: { zstd: (data, size) => decompress(data, new Uint8Array(Number(size))) },
});
const types = new Map();
const typeFor = (schema) => {
  if (!types.has(schema.id)) {
    const set = descriptor.FileDescriptorSet.decode(schema.data);
    types.set(schema.id, protobuf.Root.fromDescriptor(set).lookupType(schema.name));
  }
  return types.get(schema.id);
};
const out = {};
for await (const msg of reader.readMessages({ topics: topics.length ? topics : undefined })) {
  const channel = reader.channelsById.get(msg.channelId);
  const schema = reader.schemasById.get(channel.schemaId);
  const entry = (out[channel.topic] ??= { schema: schema.name, count: 0, first: null, children: {} });
  const decoded = typeFor(schema).decode(msg.data);
  if (entry.count === 0) entry.first = decoded.toJSON();
  const child = decoded.child_frame_id;    // the descriptor's field names are kept as they are
  if (child) entry.children[child] = (entry.children[child] ?? 0) + 1;
  entry.count += 1;
}
await handle.close();
console.log(JSON.stringify(out));
