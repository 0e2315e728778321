// A real @foxglove/ws-protocol client driven by the tests: JSON commands on stdin, JSON events on stdout.
//
// Usage: node foxglove_client.mjs ws://127.0.0.1:PORT/ [--no-deflate]  (ws offers permessage-deflate unless told not to)
// Commands (one JSON object per line):
//   {"cmd":"subscribe","topic":"/t"}                      -> events {"event":"message","topic","len","sha256","head"}
//     ("full":true adds "hex": the whole payload, for small messages)
//   {"cmd":"advertise","topic":"/t","schemaName":"pkg/T"}  -> {"event":"advertised","topic","channel"}
//   {"cmd":"publish","channel":N,"hex":"..."}
//   {"cmd":"getParameters","names":[...],"id":"x"}          -> {"event":"parameterValues",...}
//   {"cmd":"callService","service":"/s","hex":"..."}        -> {"event":"serviceResponse","hex"} or serviceCallFailure
//   {"cmd":"fetchAsset","uri":"package://p/f","id":N}        -> {"event":"fetchAssetResponse","requestId","status","error","len","sha256"}
//   {"cmd":"pause"} / {"cmd":"close"}
import { createHash } from "node:crypto";
import { createInterface } from "node:readline";
import foxglove from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = foxglove;

const url = process.argv[2];
const channels = new Map(); // topic -> channel
const services = new Map(); // name -> service
const subscriptions = new Map(); // subscription id -> topic
const full = new Set(); // subscription ids whose whole payloads are printed
const out = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");

const perMessageDeflate = !process.argv.includes("--no-deflate");
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL], { maxPayload: 0, perMessageDeflate });
const client = new FoxgloveClient({ ws });
let callId = 0;

client.on("open", () => out({ event: "open", protocol: ws.protocol, extensions: ws.extensions }));
client.on("serverInfo", (info) => out({ event: "serverInfo", capabilities: info.capabilities }));
client.on("status", (s) => out({ event: "status", level: s.level, message: s.message }));
client.on("time", (t) => out({ event: "time", timestamp: t.timestamp.toString() }));
client.on("error", (e) => out({ event: "error", message: String(e) }));
client.on("close", () => {
  out({ event: "close" });
  process.exit(0);
});
client.on("advertise", (chs) => {
  for (const ch of chs) {
    channels.set(ch.topic, ch);
    out({ event: "channel", topic: ch.topic, schemaName: ch.schemaName, encoding: ch.encoding, schemaLength: ch.schema.length });
  }
});
client.on("advertiseServices", (srvs) => {
  for (const s of srvs) {
    services.set(s.name, s);
    out({ event: "service", name: s.name, type: s.type });
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  out({
    event: "message",
    topic: subscriptions.get(subscriptionId),
    len: bytes.length,
    sha256: createHash("sha256").update(bytes).digest("hex"),
    head: Buffer.from(bytes.subarray(0, 64)).toString("hex"),
    timestamp: timestamp.toString(),
    ...(full.has(subscriptionId) ? { hex: Buffer.from(bytes).toString("hex") } : {}),
    at: Date.now(),
  });
});
client.on("parameterValues", (ev) => out({ event: "parameterValues", parameters: ev.parameters, id: ev.id }));
client.on("serviceCallResponse", (r) =>
  out({ event: "serviceResponse", callId: r.callId, encoding: r.encoding, hex: Buffer.from(r.data.buffer, r.data.byteOffset, r.data.byteLength).toString("hex") }),
);
client.on("serviceCallFailure", (f) => out({ event: "serviceCallFailure", message: f.message }));
client.on("fetchAssetResponse", (r) => {
  const bytes = r.data ? new Uint8Array(r.data.buffer, r.data.byteOffset, r.data.byteLength) : new Uint8Array(0);
  out({
    event: "fetchAssetResponse",
    requestId: r.requestId,
    status: r.status,
    error: r.error ?? "",
    len: bytes.length,
    sha256: createHash("sha256").update(bytes).digest("hex"),
  });
});

const rl = createInterface({ input: process.stdin });
rl.on("line", (line) => {
  const c = JSON.parse(line);
  try {
    if (c.cmd === "subscribe") {
      const ch = channels.get(c.topic);
      if (!ch) return out({ event: "noChannel", topic: c.topic });
      const id = client.subscribe(ch.id);
      subscriptions.set(id, c.topic);
      if (c.full) full.add(id);
      out({ event: "subscribed", topic: c.topic, id });
    } else if (c.cmd === "advertise") {
      const id = client.advertise({ topic: c.topic, encoding: "ros1", schemaName: c.schemaName });
      out({ event: "advertised", topic: c.topic, channel: id });
    } else if (c.cmd === "publish") {
      client.sendMessage(c.channel, Buffer.from(c.hex, "hex"));
    } else if (c.cmd === "getParameters") {
      client.getParameters(c.names, c.id);
    } else if (c.cmd === "callService") {
      const s = services.get(c.service);
      if (!s) return out({ event: "noService", name: c.service });
      client.sendServiceCallRequest({ serviceId: s.id, callId: ++callId, encoding: "ros1", data: new Uint8Array(Buffer.from(c.hex, "hex")) });
    } else if (c.cmd === "fetchAsset") {
      client.fetchAsset(c.uri, c.id);
    } else if (c.cmd === "pause") {
      ws._socket.pause(); // stop reading: the server must bound what it holds for us
      out({ event: "paused" });
    } else if (c.cmd === "resume") {
      ws._socket.resume();
    } else if (c.cmd === "close") {
      client.close();
    }
  } catch (e) {
    out({ event: "error", message: String(e) });
  }
});
