"""A recording as tidy tables: one Parquet file per table, for pandas, DuckDB, R or Arrow.

`export(recording, directory)` writes `<name>.<table>.parquet` for each of TABLES (name: the match
id, unless given). Every table has a `match` column, so the files of many matches read as one
table (`'study/*.states.parquet'` in DuckDB). Nested values are Parquet structs, lists and maps,
wall-clock times are UTC timestamps, and every column has its type even in an empty table. The
`match` table also names what made the recording (the recorder's `<match>.provenance.json`) and
the export (shared/provenance.py).
"""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from services.agent import library
from services.recorder.recording import Recording
from shared.game import ROLES, GameConfig
from shared.provenance import FIELDS, provenance, read_sidecar

TABLES = ("match", "states", "missiles", "shells", "actions", "switches", "events", "gaps", "adapter")

TIME = pa.timestamp("ns", tz="UTC")
SHIP = pa.struct({"x": pa.float64(), "y": pa.float64(), "vx": pa.float64(), "vy": pa.float64(),
                  "heading": pa.float64(), "alive": pa.bool_()})  # fmt: skip
FORTRESS = pa.struct({"facing": pa.float64(), "alive": pa.bool_(), "vulnerable": pa.bool_(),
                      "lock": pa.float64(), "since_shell": pa.float64()})  # fmt: skip
COUNTERS = pa.struct({"kills": pa.int64(), "missiles_fired": pa.int64(), "shield_hits": pa.int64(),
                      "frames_in_region": pa.int64(), "frames_locked": pa.int64(),
                      "deaths": pa.map_(pa.string(), pa.int64())})  # fmt: skip
PROVENANCE = pa.struct({name: pa.string() for name in FIELDS})
SCHEMAS = {
    "match": pa.schema({
        "match": pa.string(), "seed": pa.int64(), "mode": pa.string(),
        "config": pa.struct(pa.array([GameConfig().to_dict()]).type),
        "policies": pa.struct({role: pa.string() for role in ROLES}),
        "frames": pa.int64(), "kills": pa.int64(), "kills_per_minute": pa.float64(), "points": pa.int64(),
        "counters": pa.map_(pa.string(), COUNTERS), "timing": pa.map_(pa.string(), pa.float64()),
        "drops": pa.map_(pa.string(), pa.int64()), "clean": pa.bool_(), "missing_frames": pa.int64(),
        "started": TIME, "recorded_by": PROVENANCE, "exported_by": PROVENANCE,
    }),
    "states": pa.schema({
        "match": pa.string(), "frame": pa.int64(), "sent": TIME, "hash": pa.string(), "kills": pa.int64(),
        "points": pa.int64(), "bait_action": pa.int64(), "shooter_action": pa.int64(),
        "bait_obs": pa.list_(pa.float64()), "shooter_obs": pa.list_(pa.float64()),
        "bait_ship": SHIP, "shooter_ship": SHIP, "fortress": FORTRESS,
    }),
    "missiles": pa.schema({
        "match": pa.string(), "frame": pa.int64(), "index": pa.int64(), "x": pa.float64(), "y": pa.float64(),
        "vx": pa.float64(), "vy": pa.float64(), "owner": pa.string(),
    }),
    "shells": pa.schema({
        "match": pa.string(), "frame": pa.int64(), "index": pa.int64(), "x": pa.float64(), "y": pa.float64(),
        "vx": pa.float64(), "vy": pa.float64(),
    }),
    "actions": pa.schema({
        "match": pa.string(), "frame": pa.int64(), "role": pa.string(), "action": pa.int64(),
        "policy": pa.string(), "received": TIME,
    }),
    "switches": pa.schema({
        "match": pa.string(), "frame": pa.int64(), "role": pa.string(), "policy": pa.string(),
        "reason": pa.string(),
    }),
    "events": pa.schema({
        "match": pa.string(), "frame": pa.int64(), "kind": pa.string(), "role": pa.string(),
        "detail": pa.string(),
    }),
    "gaps": pa.schema({"match": pa.string(), "first": pa.int64(), "last": pa.int64()}),
    "adapter": pa.schema({
        "match": pa.string(), "frame": pa.int64(), "role": pa.string(), "partner": pa.string(),
        "policy": pa.string(), "strategy": pa.string(), "window": pa.int64(), "filled": pa.int64(),
        "out_of_library": pa.bool_(), "scores": pa.map_(pa.string(), pa.float64()),
        "belief": pa.map_(pa.string(), pa.float64()),
    }),
}  # fmt: skip


def name_of(recording: Recording) -> str:
    """The name an export is filed under: the match id, else the recording's file name."""
    return recording.start.match if recording.start else recording.path.name.removesuffix(".tsflog")


def paths(directory: str | Path, name: str) -> dict[str, Path]:
    """Where the tables of the export `name` are in `directory`."""
    return {table: Path(directory) / f"{name}.{table}.parquet" for table in TABLES}


def export(recording: Recording, directory: str | Path, name: str | None = None) -> dict[str, Path]:
    """Write one Parquet file per table of TABLES into `directory`, `<name>.<table>.parquet`."""
    name = name or name_of(recording)
    Path(directory).mkdir(parents=True, exist_ok=True)
    rows = rows_of(recording, name)
    out = paths(directory, name)
    for table, path in out.items():
        pq.write_table(pa.Table.from_pylist(rows[table], schema=SCHEMAS[table]), path)
    return out


def read(directory: str | Path, name: str) -> dict[str, pa.Table]:
    """The tables of one export (`.to_pandas()` on each)."""
    return {table: pq.read_table(path) for table, path in paths(directory, name).items()}


def rows_of(recording: Recording, name: str) -> dict[str, list[dict]]:
    """Every table's rows, as dicts by column."""
    states = recording.states
    return {
        "match": [_match(recording, name)],
        "states": [
            {
                "match": name,
                "frame": s.frame,
                "sent": s.sent_ns,
                "hash": s.hash,
                "kills": s.kills,
                "points": s.points,
                "bait_action": s.applied[0],
                "shooter_action": s.applied[1],
                "bait_obs": s.obs["bait"],
                "shooter_obs": s.obs["shooter"],
                "bait_ship": _ship(s.ships[0]),
                "shooter_ship": _ship(s.ships[1]),
                "fortress": _fortress(s.fortress),
            }  # fmt: skip
            for s in states
        ],
        "missiles": [
            {"match": name, "frame": s.frame, "index": i, **_motion(m), "owner": ROLES[int(m[4])]}
            for s in states
            for i, m in enumerate(s.missiles)
        ],
        "shells": [
            {"match": name, "frame": s.frame, "index": i, **_motion(m)}
            for s in states
            for i, m in enumerate(s.shells)
        ],
        "actions": [
            {
                "match": name,
                "frame": a.frame,
                "role": a.role,
                "action": a.action,
                "policy": a.policy,
                "received": t,
            }
            for t, a in recording.actions
        ],
        "switches": [
            {"match": name, "frame": s.frame, "role": s.role, "policy": s.policy, "reason": s.reason}
            for s in recording.switches
        ],
        "events": [
            {"match": name, "frame": e.frame, "kind": e.kind, "role": e.role, "detail": e.detail}
            for e in recording.events
        ],
        "gaps": [{"match": name, "first": first, "last": last} for first, last in recording.gaps],
        "adapter": [
            {
                "match": name,
                "frame": a.frame,
                "role": a.role,
                "partner": a.partner,
                "policy": a.policy,
                "strategy": a.strategy,
                "window": a.window,
                "filled": a.filled,
                "out_of_library": a.out_of_library,
                "scores": list(a.scores.items()),
                "belief": list(a.belief.items()),
            }  # fmt: skip
            for a in recording.adapter
        ],
    }


def _match(recording: Recording, name: str) -> dict:
    start, summary = recording.start, recording.summary
    row: dict = {"match": name, "clean": recording.clean, "missing_frames": recording.missing_frames}
    row["exported_by"] = provenance(
        **library.provenance_hashes(), config=GameConfig.from_dict(start.config) if start else None
    )
    row["recorded_by"] = read_sidecar(recording.path)  # null for a log without one
    if start:
        row |= {"seed": start.seed, "mode": start.mode, "config": start.config, "policies": start.policies}
    if summary:
        counters = {
            role: c | {"deaths": list(c.get("deaths", {}).items())} for role, c in summary.counters.items()
        }
        row |= {
            "frames": summary.frame, "kills": summary.kills, "kills_per_minute": summary.kills_per_minute,
            "points": summary.points, "counters": list(counters.items()),
            "timing": list(summary.timing.items()), "drops": list(summary.drops.items()),
        }  # fmt: skip
    row["started"] = recording.states[0].sent_ns if recording.states else None
    return row


def _ship(values: list[float]) -> dict:
    x, y, vx, vy, heading, alive = values
    return {"x": x, "y": y, "vx": vx, "vy": vy, "heading": heading, "alive": bool(alive)}


def _fortress(values: list[float]) -> dict:
    facing, alive, vulnerable, lock, since_shell = values
    return {"facing": facing, "alive": bool(alive), "vulnerable": bool(vulnerable), "lock": lock,
            "since_shell": since_shell}  # fmt: skip


def _motion(values: list[float]) -> dict:
    return dict(zip(("x", "y", "vx", "vy"), values[:4], strict=True))
