// An independent Foxglove WebSocket client (@foxglove/ws-protocol from the npm registry): connects
// to ambdaq's live view, subscribes to the topics named on the command line, and prints every
// message it receives as one JSON line {topic, logTime, data} until the given seconds have passed.
// With SLOW=1 it subscribes and then stops reading its socket: a viewer that cannot keep up.
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { WebSocket } = require("ws");

const [url, seconds, ...topics] = process.argv.slice(2);
// foxglove-sdk's server names the protocol "foxglove.sdk.v1" (the same messages as ws-protocol's
// "foxglove.websocket.v1"); FoxgloveClient leaves the subprotocol to the socket since 0.7.5
const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
const byId = new Map();
const decoder = new TextDecoder();
client.on("error", (e) => { console.error(String(e)); process.exit(2); });
client.on("advertise", (channels) => {
  for (const ch of channels) {
    if (topics.includes(ch.topic) && ch.encoding === "json") {
      byId.set(client.subscribe(ch.id), ch.topic);
    }
  }
  if (process.env.SLOW === "1") {
    setTimeout(() => ws._socket.pause(), 200);  // subscribed; now never read again
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const topic = byId.get(subscriptionId);
  if (topic) {
    process.stdout.write(JSON.stringify({ topic, logTime: String(timestamp),
                                          data: JSON.parse(decoder.decode(data)) }) + "\n");
  }
});
setTimeout(() => { client.close(); process.exit(0); }, Number(seconds) * 1000);
