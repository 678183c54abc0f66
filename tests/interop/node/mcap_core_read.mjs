// Reads an MCAP log as Foxglove does: the official TypeScript reader (@mcap/core),
// zstd chunks through fzstd, protobuf messages decoded from the schemas stored in the file
// (protobufjs's descriptor extension, as Foxglove's protobuf decoder). Prints one JSON
// object: the header, the metadata, and per topic the count, the first and last log and
// publish times (ns, strings) and the first decoded message's timestamp(s) (ns, strings).
// usage: node mcap_core_read.mjs FILE.mcap
import { open } from "node:fs/promises";

import { McapIndexedReader } from "@mcap/core";
import { decompress } from "fzstd";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const file = await open(process.argv[2], "r");
const size = (await file.stat()).size;
const readable = {
  size: async () => BigInt(size),
  read: async (offset, length) => {
    const buf = new Uint8Array(Number(length));
    await file.read(buf, 0, buf.length, Number(offset));
    return buf;
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: {
    zstd: (data, decompressedSize) => decompress(data, new Uint8Array(Number(decompressedSize))),
  },
});

const types = new Map(); // schema id -> protobufjs Type
function typeOf(schemaId) {
  if (!types.has(schemaId)) {
    const schema = reader.schemasById.get(schemaId);
    const set = descriptor.FileDescriptorSet.decode(schema.data);
    types.set(schemaId, protobuf.Root.fromDescriptor(set).lookupType(schema.name));
  }
  return types.get(schemaId);
}

function stampNs(ts) {
  return (BigInt(ts.seconds ?? 0) * 1000000000n + BigInt(ts.nanos ?? 0)).toString();
}

function stampsOf(msg) {
  const out = [];
  if (msg.timestamp) out.push(stampNs(msg.timestamp));
  for (const tf of msg.transforms ?? []) if (tf.timestamp) out.push(stampNs(tf.timestamp));
  return out;
}

const metadata = {};
for await (const m of reader.readMetadata()) metadata[m.name] = Object.fromEntries(m.metadata);

const topics = {};
for await (const message of reader.readMessages()) {
  const channel = reader.channelsById.get(message.channelId);
  let t = topics[channel.topic];
  if (t === undefined) {
    const msg = typeOf(channel.schemaId).toObject(typeOf(channel.schemaId).decode(message.data), {
      longs: String,
    });
    t = topics[channel.topic] = {
      schema: reader.schemasById.get(channel.schemaId).name,
      count: 0,
      first_log_time: message.logTime.toString(),
      first_publish_time: message.publishTime.toString(),
      stamps: stampsOf(msg),
    };
  }
  t.count += 1;
  t.last_log_time = message.logTime.toString();
}
await file.close();
console.log(
  JSON.stringify({
    profile: reader.header.profile,
    library: reader.header.library,
    message_start_time: reader.statistics?.messageStartTime.toString(),
    metadata,
    topics,
  }),
);
