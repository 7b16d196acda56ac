// An independent Foxglove WebSocket client (@foxglove/ws-protocol + Foxglove's ros2msg/CDR decoders,
// installed by scripts/setup_ros_peers.sh; run with NODE_PATH=<cache>/node_modules), used as the
// Foxglove app uses a live connection: subscribe to every channel, decode every message with the
// advertised schema, resolve the TF tree, then publish geometry_msgs/Twist on /cmd_vel (clientPublish,
// cdr) until /odom's sim time has advanced by DRIVE_S seconds.
// Usage: node foxglove_client.js URL FRAMES(comma-separated) SPEED DRIVE_S
// Prints one JSON line {"event": "connected"} and, at the end, one JSON summary line.
"use strict";
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader, MessageWriter } = require("@foxglove/rosmsg2-serialization");
const WebSocket = require("ws");

const [url, framesArg, speedArg, driveArg] = process.argv.slice(2);
const wantFrames = framesArg.split(",");
const SPEED = Number(speedArg);
const DRIVE_NS = Number(driveArg) * 1e9;
const TWIST_SCHEMA = "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n" +
  "================================================================================\n" +
  "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n";

// The Foxglove app offers both names of the (identical) protocol: foxglove-sdk servers accept only the newer
// "foxglove.sdk.v1"; ws-protocol's FoxgloveClient speaks either over the socket it is given.
const client = new FoxgloveClient({
  ws: new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]),
});
const channels = new Map(); // channel id -> {topic, reader, schemaName}
const subs = new Map(); // subscription id -> channel id
const counts = {};
const decodeErrors = {};
const schemas = {};
const edges = {}; // child -> [parent, static]
const odom = []; // [stamp_ns, x, y, vx]
let serverInfo = null;
let driving = null;
let done = false;

const stampNs = (t) => t.sec * 1e9 + (t.nanosec ?? t.nsec ?? 0);

function reachable() {
  const out = new Set(["odom"]);
  let changed = true;
  while (changed) {
    changed = false;
    for (const [child, [parent]] of Object.entries(edges)) {
      if (out.has(parent) && !out.has(child)) { out.add(child); changed = true; }
    }
  }
  return out;
}

function finish(extra) {
  if (done) return;
  done = true;
  const summary = {
    serverInfo, counts, decodeErrors, schemas, edges, reachable: [...reachable()].sort(),
    odom, channels: [...channels.values()].map((c) => c.topic), ...extra,
  };
  process.stdout.write(JSON.stringify(summary) + "\n");
  client.close();
  setTimeout(() => process.exit(0), 100);
}

client.on("serverInfo", (info) => {
  serverInfo = info;
  process.stdout.write(JSON.stringify({ event: "connected", capabilities: info.capabilities }) + "\n");
});
client.on("error", (err) => finish({ error: String(err) }));
client.on("advertise", (list) => {
  for (const ch of list) {
    let reader = null;
    try {
      reader = new MessageReader(parse(ch.schema, { ros2: true }));
    } catch (err) {
      decodeErrors[ch.topic] = `schema: ${err}`;
    }
    channels.set(ch.id, { topic: ch.topic, reader, schemaName: ch.schemaName, encoding: ch.encoding });
    schemas[ch.topic] = [ch.schemaName, ch.schemaEncoding, ch.encoding];
    subs.set(client.subscribe(ch.id), ch.id);
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const ch = channels.get(subs.get(subscriptionId));
  if (!ch || !ch.reader) return;
  let msg;
  try {
    msg = ch.reader.readMessage(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  } catch (err) {
    decodeErrors[ch.topic] = String(err);
    return;
  }
  counts[ch.topic] = (counts[ch.topic] ?? 0) + 1;
  if (ch.topic === "/tf" || ch.topic === "/tf_static") {
    for (const t of msg.transforms) edges[t.child_frame_id] = [t.header.frame_id, ch.topic === "/tf_static"];
  } else if (ch.topic === "/odom") {
    const p = msg.pose.pose.position;
    odom.push([stampNs(msg.header.stamp), p.x, p.y, msg.twist.twist.linear.x]);
    if (driving && driving.start === null) driving.start = stampNs(msg.header.stamp);
    if (driving && stampNs(msg.header.stamp) >= driving.start + DRIVE_NS) {
      clearInterval(driving.timer);
      finish({ drive: { start: driving.start, sent: driving.sent } });
    }
  }
  maybeDrive();
});

function maybeDrive() {
  if (driving || !serverInfo || channels.size === 0) return;
  const all = [...channels.values()].every((c) => counts[c.topic] > 0);
  const tree = wantFrames.every((f) => reachable().has(f));
  if (!all || !tree) return;
  // everything decoded and the TF tree resolves: now drive, as Foxglove's Teleop panel does
  const id = client.advertise({ topic: "/cmd_vel", encoding: "cdr", schemaName: "geometry_msgs/msg/Twist",
    schema: TWIST_SCHEMA, schemaEncoding: "ros2msg" });
  const writer = new MessageWriter(parse(TWIST_SCHEMA, { ros2: true }));
  const twist = writer.writeMessage({ linear: { x: SPEED, y: 0, z: 0 }, angular: { x: 0, y: 0, z: 0 } });
  driving = { start: null, sent: 0, timer: null };
  const send = () => { client.sendMessage(id, twist); driving.sent += 1; };
  send();
  driving.timer = setInterval(send, 50);
}

setTimeout(() => finish({ error: "deadline" }), Number(process.env.FOXGLOVE_CLIENT_DEADLINE_S ?? 240) * 1000);
