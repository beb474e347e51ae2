// node read.js FILE: every message of FILE through @mcap/core's McapIndexedReader, in log-time
// order; prints {"counts": {topic: n}, "ordered": bool} or {"error": message}.
import { McapIndexedReader } from "@mcap/core";
import { decompress } from "fzstd";
import { readFile } from "node:fs/promises";

const buf = await readFile(process.argv[2]);
const readable = {
  size: async () => BigInt(buf.length),
  read: async (offset, length) => buf.subarray(Number(offset), Number(offset + length)),
};
try {
  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: { zstd: (data, size) => decompress(data, new Uint8Array(Number(size))) },
  });
  const counts = {};
  let last = 0n, ordered = true;
  for await (const m of reader.readMessages()) {
    const topic = reader.channelsById.get(m.channelId).topic;
    counts[topic] = (counts[topic] ?? 0) + 1;
    if (m.logTime < last) ordered = false;
    last = m.logTime;
  }
  console.log(JSON.stringify({ counts, ordered }));
} catch (e) {
  console.log(JSON.stringify({ error: String(e.message) }));
}
