// A client of the Foxglove WebSocket protocol written by Foxglove (@foxglove/ws-protocol),
// speaking the subprotocol foxglove.websocket.v1 over the `ws` package. It subscribes to
// every /robots/<id>/pose channel the server advertises and prints one JSON line per
// event on stdout: the advertised pose channels (with their schemas), then every pose
// message (channel id, receive order, payload in base64), then "done" once every pose
// channel has sent COUNT messages.
//
// node pose_client.mjs URL ROBOTS COUNT
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const [url, robotsArg, countArg] = process.argv.slice(2);
const robots = Number(robotsArg);
const count = Number(countArg);
const out = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");

const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
ws.on("unexpected-response", (_req, res) => {
  out({ event: "refused", status: res.statusCode });
  process.exit(3);
});
const client = new FoxgloveClient({ ws });
const channels = new Map(); // subscription id -> channel
const received = new Map(); // channel id -> count

client.on("open", () => out({ event: "open", protocol: ws.protocol }));
client.on("error", (err) => out({ event: "error", message: String(err?.message ?? err) }));
client.on("advertise", (advertised) => {
  const poses = advertised.filter((c) => /^\/robots\/\d+\/pose$/.test(c.topic));
  for (const c of poses) {
    const sub = client.subscribe(c.id);
    channels.set(sub, c);
    received.set(c.id, 0);
    out({ event: "channel", id: c.id, topic: c.topic, encoding: c.encoding,
          schemaName: c.schemaName, schema: c.schema });
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const channel = channels.get(subscriptionId);
  if (channel === undefined) return;
  const n = received.get(channel.id) + 1;
  received.set(channel.id, n);
  out({ event: "message", topic: channel.topic, index: n - 1,
        payload: Buffer.from(data.buffer, data.byteOffset, data.byteLength).toString("base64") });
  if (received.size === robots && [...received.values()].every((v) => v >= count)) {
    out({ event: "done" });
    client.close();
    process.exit(0);
  }
});
client.on("close", (event) => {
  out({ event: "close", code: event?.code });
  process.exit(received.size === robots ? 0 : 4);
});
