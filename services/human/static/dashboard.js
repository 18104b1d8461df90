// The experimenter's dashboard (services/study/dashboard.py): shows the token from the link's
// fragment (#token=..., never sent in a request) over the socket, then draws each overview the
// server sends. Each running match links to the spectator's view: the participants' page (tsf.js)
// in its ?watch mode, which draws the match's frames and can send nothing that plays.
"use strict";

const token = new URLSearchParams(location.hash.slice(1)).get("token") || "";
const status = document.getElementById("status");
const dash = (window.dash = { overview: null, updates: 0, refused: null });

function rows(id, items, cells) {
  const body = document.getElementById(id);
  body.replaceChildren(...items.map((item, index) => {
    const tr = document.createElement("tr");
    for (const cell of cells(item, index)) {
      const td = document.createElement("td");
      if (cell instanceof Node) td.append(cell);
      else {
        td.textContent = String(cell);
        if (typeof cell === "number") td.className = "n";
      }
      tr.append(td);
    }
    return tr;
  }));
}

function watchLink(match) {
  const a = document.createElement("a");
  a.href = `/watch?watch=1&match=${encodeURIComponent(match)}#token=${encodeURIComponent(token)}`;
  a.target = "_blank";
  a.rel = "noopener";
  a.textContent = "watch";
  a.className = "watch";
  return a;
}

function count(n, one, many) {
  return `${n} ${n === 1 ? one : many || `${one}s`}`;
}

// Attention checks as answered: one mark each, passed or failed.
function checks(results) {
  return results.length ? results.map((passed) => (passed ? "\u2713" : "\u2717")).join(" ") : "";
}

function draw(o) {
  document.getElementById("study").textContent = `Study ${o.study}`;
  const states = Object.entries(o.counts.states).filter(([, n]) => n).map(([s, n]) => `${n} ${s}`);
  status.textContent = `${count(o.participants.length, "participant")}` +
    (states.length ? ` (${states.join(", ")})` : "") + `, ` +
    `${count(o.matches.length, "match", "matches")} running, ${o.queue.length} waiting; ` +
    `updated ${new Date().toLocaleTimeString()}`;
  rows("participants", o.participants, (p) => [p.id, p.role, p.state, `${p.done} of ${p.trials}`, p.failed,
    p.replayed, checks(p.checks), p.refused, p.match || ""]);
  const roles = Object.keys(o.counts.roles);
  document.getElementById("variant-head").replaceChildren(...["Variant", ...roles.map((r) =>
    `Trials done by ${r} participants (${o.counts.roles[r]} in all)`)].map((heading) => {
    const th = document.createElement("th");
    th.textContent = heading;
    return th;
  }));
  rows("variants", o.counts.variants, (v) => [v.variant, ...roles.map((r) => v[r])]);
  rows("matches", o.matches, (m) => [m.match, m.participant, m.variant, m.person, m.host, watchLink(m.match)]);
  rows("queue", o.queue, (q, i) => [i + 1, q.match, q.participant]);
  rows("hosts", o.hosts, (h) => [h.host, h.used, h.slots]);
}

const scheme = location.protocol === "https:" ? "wss://" : "ws://";
const socket = new WebSocket(scheme + location.host + "/ws");
socket.onopen = () => socket.send(JSON.stringify({ type: "dashboard", ...(token ? { token } : {}) }));
socket.onmessage = (event) => {
  const message = JSON.parse(event.data);
  if (!Object.hasOwn(CONTRACT.down, message.type)) return;  // not the page's contract (contract.js)
  if (message.type === "refused") {
    dash.refused = message.reason;
    document.body.classList.add("refused");
    status.textContent = `Refused: ${message.reason}. Open the link with #token=<the dashboard's token>.`;
  } else if (message.type === "study") {
    dash.overview = message;
    dash.updates += 1;
    draw(message);
  }
};
socket.onclose = () => {
  if (!dash.refused) status.textContent = "Disconnected: the study server has stopped. Reload to try again.";
};
