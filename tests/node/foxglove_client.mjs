// The Foxglove WebSocket protocol's reference client (@foxglove/ws-protocol) against a server:
// subscribes to every channel it advertises and prints, as JSON, the advertisements and the first
// messages of each topic once every topic named on the command line has WANT of them (or on timeout).
// Usage: node foxglove_client.mjs URL WANT TIMEOUT_MS TOPIC...   (NODE_PATH: the packages)
import { createRequire } from "node:module";

const require = createRequire(process.env.NODE_PATH + "/");
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { WebSocket } = require("ws");

const [url, want, timeoutMs, ...topics] = process.argv.slice(2);
// foxglove-sdk 0.30 accepts only the subprotocol name "foxglove.sdk.v1": the same protocol as the
// client's "foxglove.websocket.v1" under its new name (Foxglove's stance in its discussion #1131; the
// client checks no name since ws-protocol 0.7.5, leaving it to the handshake).
const client = new FoxgloveClient({ ws: new WebSocket(url, ["foxglove.sdk.v1"]) });
const channels = new Map();
const bySubscription = new Map();
const received = {};
let serverInfo = null;

function finish(timedOut) {
  console.log(JSON.stringify({ timedOut, serverInfo, channels: [...channels.values()], received }));
  client.close();
  process.exit(0);
}
client.on("serverInfo", (info) => { serverInfo = info; });
client.on("error", (err) => { console.error(String(err)); process.exit(3); });
client.on("advertise", (advertised) => {
  for (const channel of advertised) {
    channels.set(channel.id, channel);
    bySubscription.set(client.subscribe(channel.id), channel);
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const channel = bySubscription.get(subscriptionId);
  const list = (received[channel.topic] ??= []);
  if (list.length < Number(want)) list.push(JSON.parse(new TextDecoder().decode(data)));
  if (topics.every((t) => (received[t]?.length ?? 0) >= Number(want))) finish(false);
});
setTimeout(() => finish(true), Number(timeoutMs));
