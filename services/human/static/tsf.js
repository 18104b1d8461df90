// Team Space Fortress in the browser: draws the frames the gateway sends and sends the held keys.
// The sim is the clock; this page only draws (once per frame received, so at the game's 30 fps)
// and reports key changes. Three ways in: a seat link (?role=R&token=T, from `tsf play`), a
// spectator's link (?watch=1: a match or its live replay, playing no seat), or the study's front
// door (no token: consent, role, sessions of trials; see services/study/runner.py).
"use strict";

const COLOURS = {
  background: "rgb(12,14,28)", border: "rgb(110,110,140)", region: "rgb(50,110,60)",
  shield: "rgb(80,140,255)", opening: "rgb(255,60,200)", fortress: "rgb(200,200,215)",
  facing: "rgb(255,215,0)", missile: "rgb(255,255,140)", shell: "rgb(255,70,70)", text: "#dde",
  bait: "rgb(255,150,40)", shooter: "rgb(60,220,255)",
};
const ROLES = ["bait", "shooter"];
const HUD = 40; // px of score line above the arena
const INSTRUCTIONS = {
  bait: "You are the BAIT (the orange ship).\n\n" +
    "Fly into the green hexagon around the fortress to draw its attention: it turns toward you " +
    "and fires shells at you. Keep moving so that they miss, and keep out of the blue shield.\n\n" +
    "While the fortress fires at you, its shield opens at the back (magenta): that is when your " +
    "partner, the shooter, can destroy it. Your team's score is the number of fortresses destroyed.",
  shooter: "You are the SHOOTER (the cyan ship).\n\n" +
    "Wait outside the green hexagon, on the far side from the bait. When the fortress fires at the " +
    "bait, its shield opens at the back (magenta): fire your missiles into the opening to destroy " +
    "it.\n\nKeep out of the blue shield and away from the edge. Your team's score is the number " +
    "of fortresses destroyed.",
};
const CONTROLS = "\n\nControls: \u2190 or A turn left, \u2192 or D turn right, \u2191 or W thrust, SPACE fire.";
const KEYMAP = {
  ArrowLeft: "left", KeyA: "left", ArrowRight: "right", KeyD: "right",
  ArrowUp: "thrust", KeyW: "thrust", Space: "fire",
};

const canvas = document.getElementById("game");
const ctx = canvas.getContext("2d");
const screen = document.getElementById("screen");
const title = document.getElementById("title");
const text = document.getElementById("text");
const go = document.getElementById("go");
const no = document.getElementById("no");  // the consent's decline
const params = new URLSearchParams(location.search);
const held = { left: false, right: false, thrust: false, fire: false };
// What tests and the curious can read: the phase, the role and the last frame drawn.
const tsf = (window.tsf = { phase: "connecting", role: null, frame: null, geometry: null, drawn: 0 });
let socket = null;
let onGo = null;
let drawPending = false;

function send(message) {
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(message));
}

function show(heading, body, button, action) {
  title.textContent = heading;
  text.textContent = body;
  go.hidden = !button;
  go.textContent = button || "";
  onGo = action || null;
  no.hidden = true;
  screen.hidden = false;
}

function instructions(role, extra) {
  return (extra || INSTRUCTIONS[role] || "") + CONTROLS;
}

function ready() {
  tsf.phase = "waiting";
  send({ type: "ready" });
  show("Get ready", "Waiting for the match to start\u2026");
  canvas.focus();
}

const handlers = {
  welcome(m) {
    tsf.role = m.role;
    tsf.geometry = m;
    if (m.role === null) {  // a spectator: frames are drawn as they come
      tsf.phase = "waiting";
      show("Watching", `Match ${m.match}: waiting for its frames\u2026`);
      return;
    }
    tsf.phase = "instructions";
    show(`You play the ${m.role}`, instructions(m.role), "Start", ready);
  },
  refused(m) {
    tsf.phase = "refused";
    document.body.classList.add("refused");
    show("Not possible", m.reason);
  },
  setup(m) {
    tsf.geometry = m;
  },
  state(m) {
    tsf.frame = m;
    if (tsf.phase === "waiting") {
      tsf.phase = "playing";
      screen.hidden = true;
    }
    if (!drawPending) {
      drawPending = true;
      requestAnimationFrame(draw);
    }
  },
  end(m) {
    tsf.phase = "ended";
    release();
    show("Time is up", `Your team destroyed ${m.kills} fortress${m.kills === 1 ? "" : "es"} ` +
      `(points ${m.points}).`);
  },
  // The study's messages.
  participant(m) {
    localStorage.setItem("tsf-participant", JSON.stringify({ participant: m.participant, key: m.key }));
  },
  consent(m) {
    tsf.phase = "consent";
    show("Before we start", m.text, "I agree", () => {
      send({ type: "consent" });
      show("Thank you", "Setting up\u2026");
    });
    no.hidden = false;
  },
  declined(m) {
    tsf.phase = "done";
    show("Thank you", m.text);
  },
  wait(m) {  // a game is being set up: after a game's end, below its result
    const after = tsf.phase === "ended" ? `${text.textContent}\n\n` : "";
    show(after ? title.textContent : "Please wait", `${after}${m.reason} This takes about ${m.seconds} seconds.`);
  },
  trial(m) {
    tsf.role = m.role;
    tsf.phase = "instructions";
    const last = m.last === null || m.last === undefined ? "" :
      `Last game: your team destroyed ${m.last} fortress${m.last === 1 ? "" : "es"}.\n\n`;
    const again = m.again ? "The last game could not be completed; please play it again.\n\n" : "";
    const intro = m.trial === 1 ? instructions(m.role, m.instructions) + "\n\n" : "";
    if (m.practice) {
      show("Practice game", `${intro}This short game is for practice; it does not count. ` +
        `Your partner: ${m.agent}.`, "Start", ready);
      return;
    }
    show(`Session ${m.session} of ${m.sessions}: game ${m.trial} of ${m.trials}`,
      `${again}${last}${intro}Your partner in this session: ${m.agent}.`, "Start", ready);
  },
  queue(m) {
    const minutes = Math.max(1, Math.round(m.wait / 60));
    show("Please wait", `All game places are taken. You are number ${m.place} in the queue ` +
      `(about ${minutes} minute${minutes === 1 ? "" : "s"}). Your game starts by itself.`);
  },
  problem(m) {
    tsf.phase = "done";
    show("Something went wrong", m.text);
  },
  done(m) {
    tsf.phase = "done";
    localStorage.removeItem("tsf-participant");
    show("The end", m.code ? `${m.text}\n\nYour completion code: ${m.code}` : m.text);
  },
};

function connect() {
  const scheme = location.protocol === "https:" ? "wss://" : "ws://";
  socket = new WebSocket(scheme + location.host + "/ws");
  socket.onopen = () => {
    if (params.has("watch")) {
      send({ type: "watch" });
    } else if (params.has("token")) {
      send({ type: "join", role: params.get("role") || "", token: params.get("token") });
    } else {
      const saved = JSON.parse(localStorage.getItem("tsf-participant") || "{}");
      const participant = params.get("participant") || saved.participant;
      // A crowd-sourcing platform's worker id, under the names the common ones use in the link,
      // and its signature when the study signs its links.
      const worker = params.get("worker") || params.get("workerId") || params.get("PROLIFIC_PID");
      const sig = params.get("sig");
      send(participant ? { type: "hello", participant, key: params.get("key") || saved.key || "-" } :
        worker ? { type: "hello", worker: worker.slice(0, 64), ...(sig ? { sig: sig.slice(0, 64) } : {}) } :
        { type: "hello" });
    }
  };
  socket.onmessage = (event) => {
    const message = JSON.parse(event.data);
    const handle = handlers[message.type];
    if (handle) handle(message);
  };
  socket.onclose = (event) => {
    if (["refused", "ended", "done"].includes(tsf.phase)) return;
    tsf.phase = "closed";
    show("Disconnected", event.reason || "The connection to the game was lost. Reload the page to go on.");
  };
}

function sendKeys() {
  send({ type: "keys", ...held });
}

function release() {
  let changed = false;
  for (const k of Object.keys(held)) {
    changed = changed || held[k];
    held[k] = false;
  }
  if (changed) sendKeys();
}

function onKey(event, down) {
  if (!screen.hidden) {
    if (down && onGo && !go.hidden && (event.code === "Space" || event.code === "Enter")) {
      event.preventDefault();
      if (!event.repeat) onGo();
    }
    return;
  }
  const key = KEYMAP[event.code];
  if (!key) return;
  event.preventDefault();
  if (held[key] !== down) {
    held[key] = down;
    sendKeys();
  }
}

document.addEventListener("keydown", (e) => onKey(e, true));
document.addEventListener("keyup", (e) => onKey(e, false));
window.addEventListener("blur", release);
go.addEventListener("click", () => onGo && onGo());
no.addEventListener("click", () => {
  send({ type: "decline" });
  show("Thank you", "\u2026");
});

// Drawing. World: fortress at the origin, y up, angles in degrees counter-clockwise.
function polar(degrees, radius) {
  const a = (degrees * Math.PI) / 180;
  return [radius * Math.cos(a), radius * Math.sin(a)];
}

function draw() {
  drawPending = false;
  const g = tsf.geometry;
  const s = tsf.frame;
  if (!g || !s) return;
  const w = 2 * g.arena_x;
  const h = 2 * g.arena_y;
  if (canvas.width !== Math.round(w) || canvas.height !== Math.round(h) + HUD) {
    canvas.width = Math.round(w);
    canvas.height = Math.round(h) + HUD;
  }
  ctx.fillStyle = COLOURS.background;
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  hud(g, s);
  ctx.save();
  ctx.translate(0, HUD);
  const px = ([x, y]) => [x + g.arena_x, g.arena_y - y];
  const line = (points, colour, closed) => {
    ctx.strokeStyle = colour;
    ctx.lineWidth = 2;
    ctx.beginPath();
    points.map(px).forEach(([x, y], i) => (i ? ctx.lineTo(x, y) : ctx.moveTo(x, y)));
    if (closed) ctx.closePath();
    ctx.stroke();
  };
  const dot = (x, y, r, colour) => {
    const [cx, cy] = px([x, y]);
    ctx.fillStyle = colour;
    ctx.beginPath();
    ctx.arc(cx, cy, r, 0, 2 * Math.PI);
    ctx.fill();
  };
  const hexagon = (facing, radius) => [0, 1, 2, 3, 4, 5].map((k) => polar(facing + 60 * k, radius));
  ctx.strokeStyle = COLOURS.border;
  ctx.lineWidth = 2;
  ctx.strokeRect(1, 1, w - 2, h - 2);
  const [facing, alive, vulnerable] = s.fortress;
  line(hexagon(facing, g.region_radius), COLOURS.region, true);
  const shield = hexagon(facing, g.shield_radius); // vertex 3 is the rear
  if (vulnerable > 0) {
    line([...shield.slice(4), ...shield.slice(0, 3)], COLOURS.shield, false);
    line(shield.slice(2, 5), COLOURS.opening, false);
  } else {
    line(shield, COLOURS.shield, true);
  }
  if (alive) {
    dot(0, 0, g.fortress_radius, COLOURS.fortress);
    line([[0, 0], polar(facing, g.fortress_radius + 10)], COLOURS.facing, false);
  }
  for (const [x, y] of s.missiles) dot(x, y, 3, COLOURS.missile);
  for (const [x, y] of s.shells) dot(x, y, 3, COLOURS.shell);
  s.ships.forEach(([x, y, heading, shipAlive], i) => {
    if (!shipAlive) return;
    const role = ROLES[i];
    const r = g.ship_radius;
    const corners = [polar(heading, r + 6), polar(heading + 140, r), polar(heading + 180, r * 0.3),
      polar(heading - 140, r)].map(([dx, dy]) => px([x + dx, y + dy]));
    ctx.fillStyle = COLOURS[role];
    ctx.beginPath();
    corners.forEach(([cx, cy], k) => (k ? ctx.lineTo(cx, cy) : ctx.moveTo(cx, cy)));
    ctx.closePath();
    ctx.fill();
    const [lx, ly] = px([x, y + r + 8]);
    ctx.font = "bold 12px sans-serif";
    ctx.textAlign = "center";
    ctx.fillText(role.toUpperCase() + (role === tsf.role ? " (you)" : ""), lx, ly);
  });
  ctx.restore();
  tsf.drawn += 1;
}

function hud(g, s) {
  const left = Math.max(0, Math.ceil((s.frames - s.frame) / g.fps));
  const time = `${Math.floor(left / 60)}:${String(left % 60).padStart(2, "0")}`;
  ctx.fillStyle = COLOURS.text;
  ctx.font = "bold 18px sans-serif";
  ctx.textAlign = "left";
  ctx.fillText(`Fortresses destroyed ${s.kills}    Points ${s.points}`, 12, 27);
  ctx.textAlign = "right";
  ctx.fillText(`${tsf.role ? `You: ${tsf.role}    ` : ""}Time left ${time}`, canvas.width - 12, 27);
}

connect();
