// Generated from shared/page.py (python -m shared.page): the page's messages and their fields,
// up (page -> server) and down. Do not edit; tests/test_page_contract.py checks it.
const CONTRACT = Object.freeze({
 "up": {
  "join": [
   "role",
   "token",
   "obs"
  ],
  "watch": [
   "token",
   "match"
  ],
  "dashboard": [
   "token"
  ],
  "ready": [],
  "keys": [
   "left",
   "right",
   "thrust",
   "fire"
  ],
  "hello": [
   "participant",
   "key",
   "obs",
   "worker",
   "sig",
   "test",
   "link"
  ],
  "consent": [],
  "decline": [],
  "answer": [
   "answer"
  ]
 },
 "down": {
  "welcome": [
   "match",
   "role",
   "fps",
   "frames",
   "arena_x",
   "arena_y",
   "fortress_radius",
   "shield_radius",
   "region_radius",
   "ship_radius",
   "missile_radius",
   "shell_radius",
   "rear_arc",
   "points"
  ],
  "refused": [
   "reason"
  ],
  "setup": [
   "fps",
   "frames",
   "arena_x",
   "arena_y",
   "fortress_radius",
   "shield_radius",
   "region_radius",
   "ship_radius",
   "missile_radius",
   "shell_radius",
   "rear_arc"
  ],
  "state": [
   "frame",
   "frames",
   "ships",
   "fortress",
   "missiles",
   "shells",
   "kills",
   "points",
   "applied",
   "respawn",
   "ending",
   "obs"
  ],
  "event": [
   "frame",
   "kind",
   "role",
   "detail"
  ],
  "end": [
   "kills",
   "kills_per_minute",
   "points",
   "frame",
   "frames"
  ],
  "consent": [
   "text"
  ],
  "declined": [
   "text"
  ],
  "participant": [
   "participant",
   "key"
  ],
  "check": [
   "text",
   "options"
  ],
  "wait": [
   "reason",
   "seconds"
  ],
  "trial": [
   "role",
   "agent",
   "last",
   "session",
   "sessions",
   "trial",
   "trials",
   "again",
   "practice",
   "instructions",
   "points",
   "why"
  ],
  "queue": [
   "place",
   "wait"
  ],
  "done": [
   "text",
   "code",
   "redirect"
  ],
  "screened": [
   "text",
   "redirect"
  ],
  "problem": [
   "text"
  ],
  "stopped": [
   "text"
  ],
  "watching": [
   "match",
   "variant",
   "person"
  ],
  "study": [
   "study",
   "participants",
   "counts",
   "queue",
   "matches",
   "hosts"
  ]
 }
});
