// node read.js FILE: every message of FILE as Foxglove opens it, with @mcap/core.  Foxglove's
// MCAP source first tries McapIndexedReader, and takes it where the file has chunk indexes and
// channels; otherwise it reads the file whole with McapStreamReader (its unindexed source).  Prints
// {"reader": "indexed" | "stream", "counts": {topic: n}, "ordered": bool, "sums": {topic: sum of
// the first float64 field}} or {"error": message}.  "ordered" is the indexed reader's log-time
// order; the stream reader gives file order, which Foxglove sorts itself.
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { decompress } from "fzstd";
import { readFile } from "node:fs/promises";

const buf = await readFile(process.argv[2]);
const decompressHandlers = { zstd: (data, size) => decompress(data, new Uint8Array(Number(size))) };
const readable = {
  size: async () => BigInt(buf.length),
  read: async (offset, length) => buf.subarray(Number(offset), Number(offset + length)),
};
// ambdaq's CDR: 4-byte encapsulation header, int64 device_time, uint32 seq, uint32 status, then
// the fields; the first field's float64 sits at byte 20
const firstField = (data) => new DataView(data.buffer, data.byteOffset, data.byteLength).getFloat64(20, true);

try {
  const counts = {}, sums = {};
  let last = 0n, ordered = true, kind;
  const seen = (topic, m) => {
    counts[topic] = (counts[topic] ?? 0) + 1;
    if (m.data.byteLength >= 28) sums[topic] = (sums[topic] ?? 0) + firstField(m.data);
    if (m.logTime < last) ordered = false;
    last = m.logTime;
  };
  let indexed;
  try {
    indexed = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  } catch {
    indexed = undefined;
  }
  if (indexed && indexed.chunkIndexes.length > 0 && indexed.channelsById.size > 0) {
    kind = "indexed";
    for await (const m of indexed.readMessages()) seen(indexed.channelsById.get(m.channelId).topic, m);
  } else {
    kind = "stream";
    const reader = new McapStreamReader({ decompressHandlers });
    reader.append(buf);
    const topics = new Map();
    for (let r; (r = reader.nextRecord()) !== undefined; ) {
      if (r.type === "Channel") topics.set(r.id, r.topic);
      else if (r.type === "Message") seen(topics.get(r.channelId), r);
    }
    if (!reader.done()) throw new Error("the stream reader stopped before the end of the file");
  }
  console.log(JSON.stringify({ reader: kind, counts, ordered, sums }));
} catch (e) {
  console.log(JSON.stringify({ error: String(e.message) }));
}
