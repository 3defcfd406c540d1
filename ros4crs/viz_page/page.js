// The CRS live page: reads the visualizer node's foxglove-sdk WebSocket server (subprotocol
// foxglove.sdk.v1) and draws its two JSON channels, /viz/page/track and /viz/page/cars.
// It only ever sends subscribe and unsubscribe messages. See docs/live-view.md.
"use strict";

const TRACK_TOPIC = "/viz/page/track";
const CARS_TOPIC = "/viz/page/cars";
const SUBPROTOCOL = "foxglove.sdk.v1";
// The page server writes the WebSocket port of its visualizer into this meta tag of index.html.
const WS_PORT_META = 'meta[name="crs-ws-port"]';
const RECONNECT_MS = 2000;
// Binary "message data" frame: u8 opcode 0x01 | u32 LE subscription id | u64 LE log time ns |
// payload (here JSON text).
const MESSAGE_DATA = 0x01;
const HEADER_BYTES = 13;
// Space around the track, CSS pixels; smallest drawn car, CSS pixels (tiny cars stay visible).
const MARGIN_PX = 20;
const MIN_CAR_LENGTH_PX = 14;
const MIN_CAR_WIDTH_PX = 7;
// Radius of a drawn Lighthouse pose fix, CSS pixels.
const FIX_RADIUS_PX = 2;

const canvas = document.getElementById("track");
const header = document.getElementById("connection");
const tableBody = document.querySelector("#cars tbody");
const noCars = document.getElementById("no-cars");
const decoder = new TextDecoder();

// Colours come from page.css (custom properties on :root).
const css = getComputedStyle(document.documentElement);
const colour = (name) => css.getPropertyValue(name).trim();
const COLOURS = {
  border: colour("--track-border"),
  centre: colour("--track-centre"),
  plan: colour("--plan"),
  truth: colour("--truth"),
  fix: colour("--fix"),
  text: colour("--text"),
  status: {
    ok: colour("--status-ok"),
    degraded: colour("--status-degraded"),
    lost: colour("--status-lost"),
    none: colour("--status-none"),
  },
};

// What was last received; drawn on the next animation frame.
let track = null;
let cars = [];
let tableKey = "";
let redrawPending = false;

// The connection: advertised channels by id, our subscriptions by id ({topic, channelId}).
let channels = new Map();
let subscriptions = new Map();
let nextSubscriptionId = 1;

// A port number (1-65535) from text; null when the text is not one.
function portNumber(raw) {
  const port = raw !== null && /^[0-9]+$/.test(raw) ? Number(raw) : NaN;
  return Number.isInteger(port) && port >= 1 && port <= 65535 ? port : null;
}

// The WebSocket port: "?ws=PORT" when the address gives one, else the port the page server
// wrote into the page (its visualizer's). {port} or {error}: what to show instead.
function wsPort() {
  const raw = new URLSearchParams(location.search).get("ws");
  if (raw !== null) {
    const port = portNumber(raw);
    return port === null ? {error: "?ws= must be a port number (1-65535), e.g. ?ws=8765"} : {port};
  }
  const meta = document.querySelector(WS_PORT_META);
  const port = portNumber(meta === null ? null : meta.content);
  if (port === null) {
    return {error: "no WebSocket port: open the page from the visualizer, or add ?ws=PORT"};
  }
  return {port};
}

function setHeader(text, connected) {
  header.textContent = text;
  header.classList.toggle("connected", connected);
}

function connect(url) {
  setHeader(`connecting to ${url}…`, false);
  const socket = new WebSocket(url, [SUBPROTOCOL]);
  socket.binaryType = "arraybuffer";
  socket.onmessage = (event) => {
    if (typeof event.data === "string") {
      onJson(socket, url, JSON.parse(event.data));
    } else {
      onBinary(event.data);
    }
  };
  socket.onclose = () => {
    channels = new Map();
    subscriptions = new Map();
    setHeader(`not connected to ${url}: retrying every ${RECONNECT_MS / 1000} s`, false);
    setTimeout(() => connect(url), RECONNECT_MS);
  };
  // An error is always followed by onclose, which reconnects.
}

function send(socket, message) {
  socket.send(JSON.stringify(message));
}

function onJson(socket, url, message) {
  if (message.op === "advertise") {
    for (const channel of message.channels) {
      channels.set(channel.id, channel);
      if ((channel.topic === TRACK_TOPIC || channel.topic === CARS_TOPIC) &&
          channel.encoding === "json") {
        subscribe(socket, channel);
      }
    }
  } else if (message.op === "unadvertise") {
    for (const id of message.channelIds) {
      channels.delete(id);
      for (const [subId, sub] of subscriptions) {
        if (sub.channelId === id) {
          subscriptions.delete(subId);  // the server ends it with the channel
        }
      }
    }
  }
  setHeader(`connected to ${url}, ${channels.size} channels`, true);
}

// One subscription per topic: a channel advertised again for a topic replaces the old one.
function subscribe(socket, channel) {
  const stale = [...subscriptions].filter(([, sub]) => sub.topic === channel.topic);
  if (stale.length > 0) {
    send(socket, {op: "unsubscribe", subscriptionIds: stale.map(([id]) => id)});
    stale.forEach(([id]) => subscriptions.delete(id));
  }
  const id = nextSubscriptionId++;
  subscriptions.set(id, {topic: channel.topic, channelId: channel.id});
  send(socket, {op: "subscribe", subscriptions: [{id, channelId: channel.id}]});
}

function onBinary(buffer) {
  const view = new DataView(buffer);
  if (buffer.byteLength < HEADER_BYTES || view.getUint8(0) !== MESSAGE_DATA) {
    return;
  }
  const sub = subscriptions.get(view.getUint32(1, true));
  if (sub === undefined) {
    return;  // a subscription just cancelled
  }
  const message = JSON.parse(decoder.decode(new Uint8Array(buffer, HEADER_BYTES)));
  if (sub.topic === TRACK_TOPIC) {
    track = message;
  } else {
    cars = message.cars;
    updateTable();
  }
  requestRedraw();
}

function requestRedraw() {
  if (!redrawPending) {
    redrawPending = true;
    requestAnimationFrame(draw);
  }
}

// The world -> canvas mapping that fits the track into the canvas (y up on screen).
function fitTrack(width, height) {
  const points = [...track.left, ...track.right, ...track.centre];
  const xs = points.map((p) => p[0]);
  const ys = points.map((p) => p[1]);
  const [xMin, xMax, yMin, yMax] = [Math.min(...xs), Math.max(...xs), Math.min(...ys),
    Math.max(...ys)];
  const scale = Math.min((width - 2 * MARGIN_PX) / Math.max(xMax - xMin, 1e-6),
    (height - 2 * MARGIN_PX) / Math.max(yMax - yMin, 1e-6));
  // Centre the track's box in the canvas.
  const left = (width - scale * (xMax - xMin)) / 2;
  const top = (height - scale * (yMax - yMin)) / 2;
  return {scale, x: (x) => left + scale * (x - xMin), y: (y) => top + scale * (yMax - y)};
}

function polyline(ctx, fit, points, closed) {
  ctx.beginPath();
  points.forEach(([x, y], i) => (i === 0 ? ctx.moveTo : ctx.lineTo).call(ctx, fit.x(x), fit.y(y)));
  if (closed) {
    ctx.closePath();
  }
}

function drawTrack(ctx, fit) {
  ctx.lineJoin = "round";
  ctx.lineWidth = 2;
  ctx.strokeStyle = COLOURS.border;
  polyline(ctx, fit, track.left, true);
  ctx.stroke();
  polyline(ctx, fit, track.right, true);
  ctx.stroke();
  ctx.strokeStyle = COLOURS.centre;
  polyline(ctx, fit, track.centre, true);
  ctx.stroke();
}

// A car's rectangle centred at pose [x, y, yaw], its front marked by a white bar.
function carPath(ctx, fit, pose, size) {
  const length = Math.max(size[0] * fit.scale, MIN_CAR_LENGTH_PX);
  const width = Math.max(size[1] * fit.scale, MIN_CAR_WIDTH_PX);
  ctx.translate(fit.x(pose[0]), fit.y(pose[1]));
  ctx.rotate(-pose[2]);  // yaw is counter-clockwise, canvas angles are clockwise
  ctx.beginPath();
  ctx.rect(-length / 2, -width / 2, length, width);
  return length;
}

function drawCar(ctx, fit, car) {
  const fill = COLOURS.status[car.status] || COLOURS.status.none;
  if (car.plan.length > 1) {
    ctx.lineWidth = 2;
    ctx.strokeStyle = COLOURS.plan;
    polyline(ctx, fit, car.plan, false);
    ctx.stroke();
  }
  if (car.truth) {
    ctx.save();
    ctx.globalAlpha = 0.6;
    ctx.setLineDash([3, 2]);
    ctx.lineWidth = 1.5;
    ctx.strokeStyle = COLOURS.truth;
    carPath(ctx, fit, car.truth, car.size);
    ctx.stroke();
    ctx.restore();
  }
  if (car.estimate) {
    ctx.save();
    const length = carPath(ctx, fit, car.estimate, car.size);
    ctx.fillStyle = fill;
    ctx.fill();
    ctx.fillStyle = "#ffffff";
    ctx.fillRect(length / 2 - 3, -1.5, 2, 3);
    ctx.restore();
    ctx.fillStyle = COLOURS.text;
    ctx.fillText(car.name, fit.x(car.estimate[0]) + 10, fit.y(car.estimate[1]) - 10);
  }
  // Lighthouse pose fixes: a dot each (drawn over the car: a fix under it is still seen).
  ctx.fillStyle = COLOURS.fix;
  for (const fix of car.fixes || []) {
    ctx.beginPath();
    ctx.arc(fit.x(fix[0]), fit.y(fix[1]), FIX_RADIUS_PX, 0, 2 * Math.PI);
    ctx.fill();
  }
}

function draw() {
  redrawPending = false;
  // Draw in device pixels, coordinates in CSS pixels.
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth;
  const height = canvas.clientHeight;
  canvas.width = Math.round(width * ratio);
  canvas.height = Math.round(height * ratio);
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, width, height);
  ctx.font = "12px system-ui, sans-serif";
  if (track === null) {
    ctx.fillStyle = COLOURS.text;
    ctx.fillText("waiting for the track…", MARGIN_PX, MARGIN_PX);
    return;
  }
  const fit = fitTrack(width, height);
  drawTrack(ctx, fit);
  cars.forEach((car) => drawCar(ctx, fit, car));
}

function cell(row, text, className) {
  const td = row.insertCell();
  td.textContent = text;
  if (className) {
    td.className = className;
  }
  return td;
}

// Three significant digits of an online parameter (its value or std).
function significant(value) {
  return value === null ? "–" : Number(value.toPrecision(3)).toString();
}

// One row per car (name, status, laps, last lap), one under it with the status's reason and one
// per online parameter (value ± std; "prior" while the data do not inform it).
function updateTable() {
  const key = JSON.stringify(cars.map((c) => [
    c.name, c.status, c.reason, c.laps, c.last_lap_s,
    (c.parameters || []).map((p) => [p.name, significant(p.value), significant(p.std), p.informed]),
  ]));
  if (key === tableKey) {
    return;  // unchanged: no DOM work at 30 Hz
  }
  tableKey = key;
  tableBody.replaceChildren();
  for (const car of cars) {
    const row = tableBody.insertRow();
    cell(row, car.name);
    const badge = document.createElement("span");
    badge.textContent = car.status;
    badge.style.background = COLOURS.status[car.status] || COLOURS.status.none;
    cell(row, "", "status").append(badge);
    cell(row, String(car.laps));
    cell(row, car.last_lap_s === null ? "–" : `${car.last_lap_s.toFixed(2)} s`);
    if (car.reason) {
      const reason = cell(tableBody.insertRow(), car.reason, "reason");
      reason.colSpan = 4;
    }
    for (const p of car.parameters || []) {  // none from a visualizer older than them
      const text = `${p.name} ${significant(p.value)} ± ${significant(p.std)}` +
        (p.informed ? "" : " (prior)");
      const parameter = cell(tableBody.insertRow(), text, "parameter");
      parameter.colSpan = 4;
    }
  }
  noCars.hidden = cars.length > 0;
}

window.addEventListener("resize", requestRedraw);
requestRedraw();
const ws = wsPort();
if (ws.error) {
  setHeader(ws.error, false);
} else {
  connect(`ws://${location.hostname || "127.0.0.1"}:${ws.port}`);
}
