// Team Space Fortress in the browser: draws the frames the gateway sends and sends the held keys.
// The sim is the clock; this page only draws (once per frame received, so at the game's 30 fps)
// and reports key changes. Three ways in: a seat link (?role=R&token=T, from `tsf play`), a
// spectator's link (?watch=1: a match or its live replay, playing no seat), or the study's front
// door (no token: consent, role, sessions of trials; see services/study/runner.py). Every message in
// and out is one of the page's contract (shared/page.py, generated into contract.js, loaded first).
"use strict";

const COLOURS = {
  background: "rgb(12,14,28)", border: "rgb(110,110,140)", region: "rgb(50,110,60)",
  shield: "rgb(80,140,255)", opening: "rgb(255,60,200)", fortress: "rgb(200,200,215)",
  facing: "rgb(255,215,0)", missile: "rgb(255,255,140)", shell: "rgb(255,70,70)", text: "#dde",
};
const ROLES = ["bait", "shooter"];
const HUD = 40; // px of score line above the arena
const INSTRUCTIONS = {
  bait: "You are the BAIT (the orange ship).\n\n" +
    "Fly into the green hexagon around the fortress to draw its attention: it turns toward you " +
    "and fires shells at you. Keep moving so that they miss.\n\n" +
    "While the fortress fires at you, its shield opens at the back (magenta): that is when your " +
    "partner, the shooter, can destroy it.",
  shooter: "You are the SHOOTER (the cyan ship).\n\n" +
    "Wait outside the green hexagon, on the far side from the bait. When the fortress fires at the " +
    "bait, its shield opens at the back (magenta): fire your missiles into the opening to destroy " +
    "it.",
};
// The team's score, and how points are counted where the page shows them (`points`: the rule the
// server sends, null where the study hides points).
function scoring(rule) {
  const score = "\n\nYour team's score is the number of fortresses destroyed.";
  if (!rule) return score;
  const signed = (n) => (n > 0 ? `+${n}` : `${n}`);
  return `${score} The game also counts points: ${signed(rule.kill)} for each fortress destroyed, ` +
    `${signed(rule.death)} for each ship destroyed (yours or your teammate's), ${signed(rule.shield_hit)} ` +
    "for each missile that hits the closed shield. Points can go below zero.";
}
// Every rule that kills a ship (shared/game.py DEATH_CAUSES: shell, border, shield), for both roles.
const DEATHS = "\n\nYour ship is destroyed if a shell hits it, if it touches the blue shield, or if it " +
  "leaves the arena (the edge kills). A destroyed ship stays out until the round ends: when the " +
  "fortress is destroyed, or one second after both ships are down. An agent teammate whose partner " +
  "is down flies into the fortress's shield (or the arena's edge, when that is nearer) on purpose, " +
  "so that you both come back sooner.";
const CONTROLS = "\n\nControls: \u2190 or A turn left, \u2192 or D turn right, \u2191 or W thrust, SPACE fire; " +
  "M sound on or off.";
const OWN = ["participant", "key", "worker", "workerId", "watch", "match", "role", "token", "obs", "sig"]; // not the link's
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
const soundButton = document.getElementById("sound");
const no = document.getElementById("no");  // the consent's decline
const params = new URLSearchParams(location.search);
const held = { left: false, right: false, thrust: false, fire: false };
// What tests and the curious can read: the phase, the role, the last frame drawn, the events still
// shown and what the page says over the arena; `onDraw(state)`, if set, is called after each frame
// drawn (bench/human.py times it).
const tsf = (window.tsf = {
  phase: "connecting", role: null, frame: null, geometry: null, drawn: 0, events: [], said: [], onDraw: null,
  points: null, study: false, // how points count (null: not shown); whether this is the study's page
  watching: null, // a dashboard spectator's match: {variant, person}
});
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
  return (extra || INSTRUCTIONS[role] || "") + scoring(tsf.points) + DEATHS + CONTROLS;
}

function ready() {
  tsf.phase = "waiting";
  send({ type: "ready" });
  show("Get ready", "Waiting for the match to start\u2026");
  canvas.focus();
}

const handlers = {
  watching(m) {  // the dashboard's spectator: which variant plays, and which seat is the person's
    tsf.watching = m;
  },
  welcome(m) {
    tsf.role = m.role;
    tsf.geometry = m;
    if (m.role === null) {  // a spectator: frames are drawn as they come
      tsf.phase = "waiting";
      const who = tsf.watching ? `\n\nVariant ${tsf.watching.variant}; the person plays the ${tsf.watching.person}.` : "";
      show("Watching", `Match ${m.match}: waiting for its frames\u2026${who}`);
      return;
    }
    tsf.phase = "instructions";
    tsf.points = m.points || null;
    show(`You play the ${m.role}`, instructions(m.role), "Start", ready);
  },
  refused(m) {
    tsf.phase = "refused";
    document.body.classList.add("refused");
    show("Not possible", m.reason);
  },
  setup(m) {
    tsf.geometry = m;
    tsf.events = [];
  },
  event(m) {
    const s = tsf.frame;
    const ship = s && ROLES.includes(m.role) ? s.ships[ROLES.indexOf(m.role)] : null;
    tsf.events.push({ ...m, at: ship && m.kind !== "kill" ? [ship[0], ship[1]] : [0, 0] });
    sound(m);
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
    const result = `Your team destroyed ${m.kills} fortress${m.kills === 1 ? "" : "es"}` +
      (tsf.points ? ` (points ${m.points}).` : ".");
    if (m.frame < m.frames) {  // stopped before its time: never "Time is up" with time left
      const left = Math.ceil((m.frames - m.frame) / ((tsf.geometry && tsf.geometry.fps) || 30));
      show("The game was stopped", `This game ended early, with ${left} s left. ${result}` +
        (tsf.study ? "\n\nYour progress is kept; what happens next is shown here." : ""));
      return;
    }
    show("Time is up", result);
  },
  // The study's messages.
  participant(m) {
    tsf.study = true;
    localStorage.setItem("tsf-participant", JSON.stringify({ participant: m.participant, key: m.key }));
  },
  consent(m) {
    tsf.study = true;
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
    tsf.study = true;
    tsf.role = m.role;
    tsf.phase = "instructions";
    tsf.points = m.points || null;
    const last = m.last === null || m.last === undefined ? "" :
      `Last game: your team destroyed ${m.last} fortress${m.last === 1 ? "" : "es"}.\n\n`;
    const again = m.again ? `${m.why || "The last game could not be completed; please play it again."}\n\n` : "";
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
    farewell("The end", m.code ? `${m.text}\n\nYour completion code: ${m.code}` : m.text, m.redirect);
  },
  check(m) {  // an attention check: one button per option, the question says which
    tsf.phase = "check";
    show("A quick check", m.text);
    const buttons = document.createElement("div");
    for (const option of m.options) {
      const button = document.createElement("button");
      button.textContent = option;
      button.className = "answer";
      button.addEventListener("click", () => {
        send({ type: "answer", answer: option });
        tsf.phase = "answered";
        show("Thank you", "Setting up\u2026");
      });
      buttons.append(button, " ");
    }
    text.append("\n\n", buttons);
  },
  screened(m) {
    farewell("Thank you", m.text, m.redirect);
  },
  stopped(m) {  // the server stops: progress kept, the participant's resume key too
    tsf.phase = "stopped";
    release();
    show("The study has stopped", m.text);
  },
};

// The study is over for this participant: say so, and go back to the platform's address if given.
function farewell(heading, body, redirect) {
  tsf.phase = "done";
  localStorage.removeItem("tsf-participant");
  if (!redirect) return show(heading, body);
  show(heading, `${body}\n\nTaking you back to the study's site in 5 seconds\u2026`, "Go back now",
    () => location.assign(redirect));
  setTimeout(() => location.assign(redirect), 5000);
}

function connect() {
  const scheme = location.protocol === "https:" ? "wss://" : "ws://";
  socket = new WebSocket(scheme + location.host + "/ws");
  socket.onopen = () => {
    if (params.has("watch")) {
      // the study's dashboard names the match, and its token comes in the fragment (never sent in a request)
      const token = new URLSearchParams(location.hash.slice(1)).get("token");
      send(params.has("match") ? { type: "watch", match: params.get("match"), ...(token ? { token } : {}) } : { type: "watch" });
    } else if (params.has("token")) {
      // ?obs=1: the seat's observation values too (a scripted player's, bench/human.py)
      send({ type: "join", role: params.get("role") || "", token: params.get("token"),
        ...(params.has("obs") ? { obs: true } : {}) });
    } else {
      const saved = JSON.parse(localStorage.getItem("tsf-participant") || "{}");
      const participant = params.get("participant") || saved.participant;
      // A crowd-sourcing platform's worker id, under the names the common ones use in the link,
      // and its signature when the study signs its links.
      const worker = params.get("worker") || params.get("workerId") || params.get("PROLIFIC_PID");
      const sig = params.get("sig");
      // The link's other parameters (a platform's study and session ids: the study's config names them).
      const link = Object.fromEntries([...params].filter(([k, v]) => v && !OWN.includes(k))
        .slice(0, 6).map(([k, v]) => [k.slice(0, 64), v.slice(0, 64)]));
      send(participant ? { type: "hello", participant, key: params.get("key") || saved.key || "-" } :
        { type: "hello", ...(worker ? { worker: worker.slice(0, 64) } : {}),
          ...(sig ? { sig: sig.slice(0, 64) } : {}), link });
    }
  };
  socket.onmessage = (event) => {
    const message = JSON.parse(event.data);
    if (!Object.hasOwn(CONTRACT.down, message.type)) return;  // not the page's contract (contract.js)
    const handle = handlers[message.type];
    if (handle) handle(message);
  };
  socket.onclose = (event) => {
    if (["refused", "done", "stopped"].includes(tsf.phase) || (tsf.phase === "ended" && !tsf.study)) return;
    tsf.phase = "closed";
    const kept = tsf.study ? " Your progress so far is kept: reload this page, or open your study link " +
      "again, to go on where you left off." : " Reload the page to go on.";
    show("Disconnected", (event.reason ? `${event.reason.replace(/\.$/, "")}.` : "The connection to the game was lost.") + kept);
  };
}

function sendKeys() {  // the fields the contract names, each held or not
  send({ type: "keys", ...Object.fromEntries(CONTRACT.up.keys.map((key) => [key, held[key]])) });
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
  if (down && event.code === "KeyM" && !event.repeat) toggleSound();
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
soundButton.addEventListener("click", toggleSound);

// Sound: generated by WebAudio (no files), off until the person turns it on (M or the button).
let audio = null;
function toggleSound() {
  const on = localStorage.getItem("tsf-sound") !== "on";
  localStorage.setItem("tsf-sound", on ? "on" : "off");
  soundButton.textContent = `Sound: ${on ? "on" : "off"} (M)`;
  if (on && !audio) audio = new AudioContext();
  soundButton.blur();
  canvas.focus();
}
soundButton.textContent = `Sound: ${localStorage.getItem("tsf-sound") === "on" ? "on" : "off"} (M)`;

const SOUNDS = { // kind -> [start Hz, end Hz, seconds, wave]
  kill: [300, 1200, 0.5, "square"], death: [400, 60, 0.6, "sawtooth"], shield_hit: [900, 700, 0.08, "triangle"],
  reset: [500, 800, 0.2, "sine"], respawn: [500, 800, 0.2, "sine"],
};

function sound(event) {
  const tone = SOUNDS[event.kind];
  if (!tone || localStorage.getItem("tsf-sound") !== "on") return;
  if (!audio) audio = new AudioContext();
  const [from, to, seconds, wave] = tone;
  const t = audio.currentTime;
  const osc = audio.createOscillator();
  const gain = audio.createGain();
  osc.type = wave;
  osc.frequency.setValueAtTime(from, t);
  osc.frequency.exponentialRampToValueAtTime(to, t + seconds);
  gain.gain.setValueAtTime(0.15, t);
  gain.gain.exponentialRampToValueAtTime(0.001, t + seconds);
  osc.connect(gain).connect(audio.destination);
  osc.start(t);
  osc.stop(t + seconds);
}

// Drawing. World: fortress at the origin, y up, angles in degrees counter-clockwise. A frame's
// picture is a function of the numbers, the seat and the events still shown, whose effects age in
// game frames, never by the clock: a given state always draws the same pixels (tsf.render, below,
// is how the screenshot test draws given states).
const SHADES = { // each role's light, body and dark colours
  bait: ["rgb(255,214,160)", "rgb(255,150,40)", "rgb(150,80,10)"],
  shooter: ["rgb(190,250,255)", "rgb(60,220,255)", "rgb(10,110,150)"],
};
const SHOWN = { kill: 45, death: 24, shield_hit: 6, respawn: 15, reset: 15, fortress_respawn: 15 }; // frames
const YOU_DIED = {
  shell: "A shell hit you", shield: "You flew into the shield", border: "You flew out of the arena: the edge kills",
};
const DOWN = { shell: "hit by a shell", shield: "flew into the shield", border: "flew out of the arena" };

function polar(degrees, radius) {
  const a = (degrees * Math.PI) / 180;
  return [radius * Math.cos(a), radius * Math.sin(a)];
}

function draw() {
  drawPending = false;
  if (tsf.geometry && tsf.frame) render(tsf.geometry, tsf.frame);
}

// A hook for tests: draw `state` as the page would, after `events` arrived, for the seat `role`.
tsf.render = (geometry, state, events, role) => {
  Object.assign(tsf, { geometry, role, phase: "test", events: [], frame: state });
  screen.hidden = true;
  events.forEach(handlers.event);
  render(geometry, state);
};

function render(g, s) {
  const w = 2 * g.arena_x;
  const h = 2 * g.arena_y;
  if (canvas.width !== Math.round(w) || canvas.height !== Math.round(h) + HUD) {
    canvas.width = Math.round(w);
    canvas.height = Math.round(h) + HUD;
  }
  // Events stay while their effect shows, and a death while that ship is still down.
  tsf.events = tsf.events.filter((e) => s.frame - e.frame < (SHOWN[e.kind] || 0) ||
    (e.kind === "death" && !s.ships[ROLES.indexOf(e.role)][3]));
  const age = (e) => s.frame - e.frame;
  const shown = tsf.events.filter((e) => age(e) >= 0);
  ctx.fillStyle = COLOURS.background;
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.save();
  ctx.translate(0, HUD);
  const px = ([x, y]) => [x + g.arena_x, g.arena_y - y];
  const path = (points, closed) => {
    ctx.beginPath();
    points.map(px).forEach(([x, y], i) => (i ? ctx.lineTo(x, y) : ctx.moveTo(x, y)));
    if (closed) ctx.closePath();
  };
  const stroke = (points, colour, width, closed) => {
    path(points, closed);
    ctx.strokeStyle = colour;
    ctx.lineWidth = width;
    ctx.stroke();
  };
  const disc = ([x, y], r, fill) => {
    const [cx, cy] = px([x, y]);
    ctx.fillStyle = fill;
    ctx.beginPath();
    ctx.arc(cx, cy, r, 0, 2 * Math.PI);
    ctx.fill();
  };
  const hexagon = (facing, radius) => [0, 1, 2, 3, 4, 5].map((k) => polar(facing + 60 * k, radius));
  ctx.strokeStyle = COLOURS.border;
  ctx.lineWidth = 2;
  ctx.strokeRect(1, 1, w - 2, h - 2);

  // The fortress: the activation region, the shield (its rear open while vulnerable), the body.
  const [facing, alive, vulnerable] = s.fortress;
  path(hexagon(facing, g.region_radius), true);
  ctx.fillStyle = "rgba(50,110,60,0.10)";
  ctx.fill();
  stroke(hexagon(facing, g.region_radius), COLOURS.region, 2, true);
  if (alive) {
    const shield = hexagon(facing, g.shield_radius); // vertex 3 is the rear
    const hit = shown.some((e) => e.kind === "shield_hit");
    const shieldColour = hit ? "rgb(220,235,255)" : COLOURS.shield;
    if (vulnerable > 0) {
      const rear = facing + 180;
      const arc = g.rear_arc / 2;
      const [cx, cy] = px([0, 0]); // the open arc, a wedge out to twice the shield (canvas angles turn the other way)
      ctx.beginPath();
      ctx.moveTo(cx, cy);
      ctx.arc(cx, cy, g.shield_radius * 2.2, (-(rear + arc) * Math.PI) / 180, (-(rear - arc) * Math.PI) / 180);
      ctx.closePath();
      ctx.fillStyle = "rgba(255,60,200,0.16)";
      ctx.fill();
      stroke([...shield.slice(4), ...shield.slice(0, 3)], shieldColour, 3, false);
      stroke(shield.slice(2, 5), "rgba(255,60,200,0.35)", 9, false);
      stroke(shield.slice(2, 5), COLOURS.opening, 3, false);
      const [lx, ly] = px(polar(rear, g.shield_radius * 2.2 + 14));
      label("OPEN", lx, ly + 5, COLOURS.opening, "bold 14px sans-serif");
    } else {
      stroke(shield, "rgba(80,140,255,0.3)", 7, true);
      stroke(shield, shieldColour, 3, true);
    }
    const [cx, cy] = px([0, 0]);
    const r = g.fortress_radius;
    const body = ctx.createRadialGradient(cx - r / 3, cy - r / 3, r / 6, cx, cy, r);
    body.addColorStop(0, "rgb(250,250,255)");
    body.addColorStop(0.6, COLOURS.fortress);
    body.addColorStop(1, "rgb(90,90,110)");
    disc([0, 0], r, body);
    ctx.lineCap = "round";
    stroke([polar(facing, r * 0.4), polar(facing, r + 10)], COLOURS.facing, 5, false);
    ctx.lineCap = "butt";
  }

  for (const [x, y] of s.missiles) {
    disc([x, y], 5, "rgba(255,255,140,0.25)");
    disc([x, y], 2.5, COLOURS.missile);
  }
  for (const [x, y] of s.shells) {
    disc([x, y], 5, "rgba(255,70,70,0.3)");
    disc([x, y], 3, COLOURS.shell);
  }
  s.ships.forEach(([x, y, heading, shipAlive], i) => {
    if (shipAlive) ship(g, px([x, y]), heading, ROLES[i], (s.applied || [0, 0])[i] & 2, s.frame);
  });

  // Effects: explosions where a ship died and where the fortress fell, rings where ships come back.
  for (const e of shown) {
    const p = Math.min(1, age(e) / SHOWN[e.kind]);
    if (e.kind === "death" || e.kind === "kill") {
      const big = e.kind === "kill" ? 3 : 1;
      explosion(px(e.at), big, p, e.kind === "kill" ? COLOURS.facing : SHADES[e.role][1]);
    } else if (e.kind === "respawn" || e.kind === "reset") {
      s.ships.forEach(([x, y], i) => {
        if (e.kind === "reset" || ROLES[i] === e.role) ring(px([x, y]), 40 * (1 - p) + 12, 1 - p, SHADES[ROLES[i]][0]);
      });
    } else if (e.kind === "fortress_respawn") {
      ring(px([0, 0]), g.shield_radius * (1 + 2 * (1 - p)), 1 - p, COLOURS.shield);
    }
  }
  ctx.restore();
  hud(g, s);
  banner(g, s, shown);
  tsf.drawn += 1;
  if (tsf.onDraw) tsf.onDraw(s);
}

function label(text, x, y, colour, font) {
  ctx.font = font;
  ctx.textAlign = "center";
  ctx.fillStyle = colour;
  ctx.fillText(text, x, y);
}

function ship(g, [cx, cy], heading, role, thrusting, frame) {
  const r = g.ship_radius;
  const [light, body, dark] = SHADES[role];
  if (role === tsf.role) { // the person's own ship: a halo to find it at a glance
    ring([cx, cy], r + 9, 0.5, light);
  }
  ctx.save();
  ctx.translate(cx, cy);
  ctx.rotate((-heading * Math.PI) / 180); // the nose along +x
  if (thrusting) {
    const flame = r * (frame % 2 ? 1.5 : 1.2);
    ctx.fillStyle = "rgba(255,200,80,0.9)";
    ctx.beginPath();
    ctx.moveTo(-r * 0.5, -r * 0.35);
    ctx.lineTo(-r * 0.5 - flame, 0);
    ctx.lineTo(-r * 0.5, r * 0.35);
    ctx.fill();
  }
  const shade = ctx.createLinearGradient(0, -r, 0, r);
  shade.addColorStop(0, light);
  shade.addColorStop(0.5, body);
  shade.addColorStop(1, dark);
  ctx.fillStyle = shade;
  ctx.beginPath();
  ctx.moveTo(r + 6, 0);
  ctx.lineTo(-r * 0.8, -r * 0.75);
  ctx.lineTo(-r * 0.35, 0);
  ctx.lineTo(-r * 0.8, r * 0.75);
  ctx.closePath();
  ctx.fill();
  ctx.strokeStyle = light;
  ctx.lineWidth = 1;
  ctx.stroke();
  ctx.fillStyle = dark;
  ctx.beginPath();
  ctx.arc(r * 0.25, 0, r * 0.22, 0, 2 * Math.PI);
  ctx.fill();
  ctx.restore();
  const who = role === tsf.role ? " (you)" : tsf.watching && role === tsf.watching.person ? " (person)" : "";
  label(role.toUpperCase() + who, cx, cy - r - 12, body, "bold 12px sans-serif");
}

function ring([cx, cy], radius, alpha, colour) {
  ctx.globalAlpha = Math.max(0, alpha);
  ctx.strokeStyle = colour;
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.arc(cx, cy, radius, 0, 2 * Math.PI);
  ctx.stroke();
  ctx.globalAlpha = 1;
}

function explosion([cx, cy], size, p, colour) {
  const glow = ctx.createRadialGradient(cx, cy, 0, cx, cy, 30 * size * (0.3 + p));
  glow.addColorStop(0, `rgba(255,255,220,${0.9 * (1 - p)})`);
  glow.addColorStop(1, "rgba(255,120,40,0)");
  ctx.fillStyle = glow;
  ctx.beginPath();
  ctx.arc(cx, cy, 30 * size * (0.3 + p), 0, 2 * Math.PI);
  ctx.fill();
  ring([cx, cy], 10 + 40 * size * p, 1 - p, colour);
  ctx.globalAlpha = 1 - p;
  ctx.fillStyle = colour;
  for (let k = 0; k < 8 * size; k++) { // debris on fixed spokes: the same picture every time
    const [dx, dy] = polar((360 * k) / (8 * size) + 17 * k, (8 + 45 * size * p) * (0.7 + 0.3 * ((k * 7) % 5) / 4));
    ctx.fillRect(cx + dx - 2, cy - dy - 2, 4, 4);
  }
  ctx.globalAlpha = 1;
}

// What the frame means, in words: deaths and why, when the person's ship comes back (a count-down
// once both ships are down; the partner agent ending the round on purpose), a kill.
function banner(g, s, shown) {
  const lines = [];
  const lastDeath = (role) => shown.filter((e) => e.kind === "death" && e.role === role).pop();
  const me = ROLES.indexOf(tsf.role);
  if (shown.some((e) => e.kind === "kill" && e.frame > s.frame - SHOWN.kill)) {
    lines.push(["Fortress destroyed!", "rgb(120,255,140)"]);
  }
  for (const [i, role] of ROLES.entries()) {
    if (s.ships[i][3]) continue;
    const death = lastDeath(role);
    const cause = death ? death.detail : "";
    if (i === me) lines.push([YOU_DIED[cause] || "Your ship is down", "rgb(255,120,110)"]);
    else lines.push([`${me < 0 ? role.toUpperCase() : "Your teammate"} ${DOWN[cause] || "is down"}`, "#dde"]);
  }
  if (s.respawn !== null && s.respawn !== undefined) {
    lines.push([`Both ships are down: ${me < 0 ? "they respawn" : "you respawn"} in ${(Math.ceil((10 * s.respawn) / g.fps) / 10).toFixed(1)} s`,
      "rgb(255,230,120)"]);
  } else if (me >= 0 && !s.ships[me][3]) {
    lines.push(s.ending ? ["Your teammate ends the round so you can respawn", "rgb(255,230,120)"] :
      [s.fortress[1] ? "You respawn when the fortress falls or both ships are down" :
        "You respawn with the fortress", "#dde"]);
  }
  tsf.said = lines.map(([text]) => text);
  ctx.font = "bold 18px sans-serif";
  ctx.textAlign = "center";
  lines.forEach(([text, colour], k) => {
    const y = HUD + 34 + 30 * k;
    const width = ctx.measureText(text).width + 24;
    ctx.fillStyle = "rgba(12,14,28,0.8)";
    ctx.fillRect(canvas.width / 2 - width / 2, y - 21, width, 28);
    ctx.fillStyle = colour;
    ctx.fillText(text, canvas.width / 2, y);
  });
}

function hud(g, s) {
  const left = Math.max(0, Math.ceil((s.frames - s.frame) / g.fps));
  const time = `${Math.floor(left / 60)}:${String(left % 60).padStart(2, "0")}`;
  ctx.fillStyle = COLOURS.text;
  ctx.font = "bold 18px sans-serif";
  ctx.textAlign = "left";
  ctx.fillText(`Fortresses destroyed ${s.kills}` + (tsf.points || !tsf.study ? `    Points ${s.points}` : ""), 12, 27);
  ctx.textAlign = "right";
  const seat = tsf.role ? `You: ${tsf.role}    ` :
    tsf.watching ? `Variant ${tsf.watching.variant}, person: ${tsf.watching.person}    ` : "";
  ctx.fillText(`${seat}Time left ${time}`, canvas.width - 12, 27);
}

connect();
