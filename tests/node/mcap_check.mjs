// Reads an MCAP file with @mcap/core (the MCAP authors' TypeScript reader, the one Foxglove uses):
// every record through the stream reader with CRCs checked, then every message again through the
// indexed reader (summary, chunk indexes, message indexes), and prints what it found as JSON.
// Usage: node mcap_check.mjs FILE   (NODE_PATH names the node_modules holding @mcap/core, @mcap/support)
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";

const require = createRequire(process.env.NODE_PATH + "/");
const { McapStreamReader, McapIndexedReader } = require("@mcap/core");
const { loadDecompressHandlers } = require("@mcap/support");

const buf = new Uint8Array(await readFile(process.argv[2]));
const decompressHandlers = await loadDecompressHandlers();
const out = { stream: { records: {}, messages: 0, jsonErrors: 0 }, indexed: { messages: 0, byTopic: {} } };

const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
stream.append(buf);
const encodingOf = new Map();
for (let record; (record = stream.nextRecord()); ) {
  out.stream.records[record.type] = (out.stream.records[record.type] ?? 0) + 1;
  if (record.type === "Channel") encodingOf.set(record.id, record.messageEncoding);
  if (record.type === "Message") {
    out.stream.messages++;
    if (encodingOf.get(record.channelId) === "json") {
      try { JSON.parse(new TextDecoder().decode(record.data)); } catch { out.stream.jsonErrors++; }
    }
  }
}
out.stream.done = stream.done();

const readable = {
  size: async () => BigInt(buf.length),
  read: async (offset, length) => buf.subarray(Number(offset), Number(offset + length)),
};
const indexed = await McapIndexedReader.Initialize({ readable, decompressHandlers });
out.indexed.statisticsMessageCount = Number(indexed.statistics?.messageCount ?? -1);
out.indexed.channels = indexed.channelsById.size;
for await (const message of indexed.readMessages({ validateCrcs: true })) {
  out.indexed.messages++;
  const topic = indexed.channelsById.get(message.channelId).topic;
  out.indexed.byTopic[topic] = (out.indexed.byTopic[topic] ?? 0) + 1;
}
console.log(JSON.stringify(out));
