"""The recording: an append-only, crash-safe log of everything a match put on the bus.

File layout (docs/recording.md): the 8-byte magic `TSFLOG1\\n`, then records, each framed as

    u32 little-endian payload length | u32 little-endian CRC-32 of the payload | payload

The payload is a msgpack map: {"key": bus key, "t": receive time (ns since the epoch),
"data": the message bytes exactly as received} or, for frames the recorder did not see,
{"gap": [first missing frame, last missing frame]}. A crash can only tear the last record; opening
the log for appending detects a torn or corrupt tail by its length and checksum and cuts it off.
Readers skip a damaged record and resume at the next intact one, and say which bytes they skipped.
"""

from __future__ import annotations

import os
import struct
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import msgpack

from shared.errors import UsageError

MAGIC = b"TSFLOG1\n"
HEADER = struct.Struct("<II")
MAX_RECORD = 1 << 20


@dataclass(frozen=True)
class Record:
    key: str  # "" for a gap record
    t: int
    data: bytes  # the message as it was on the bus
    gap: tuple[int, int] | None = None


@dataclass(frozen=True)
class Damage:
    """Bytes [start, end) of a log that hold no intact record. `torn`: they are the end of the file
    and the record there runs past it (a write cut short); otherwise the bytes are corrupt, and the
    reader resumed at the next intact record (or the file ended)."""

    start: int
    end: int
    torn: bool = False

    def __str__(self) -> str:
        what = "torn tail" if self.torn else "damaged"
        return f"{what} at bytes {self.start}-{self.end - 1}"


def _record_at(data: bytes, offset: int) -> tuple[int, Record] | None:
    """The intact record that starts at `offset` and the offset after it, or None."""
    if offset + HEADER.size > len(data):
        return None
    length, crc = HEADER.unpack_from(data, offset)
    end = offset + HEADER.size + length
    if length > MAX_RECORD or end > len(data):
        return None
    payload = data[offset + HEADER.size : end]
    if zlib.crc32(payload) != crc:
        return None
    try:
        item = msgpack.unpackb(payload, raw=False)
    except (ValueError, TypeError, msgpack.UnpackException):
        return None
    match item:
        case {"t": int(t), "gap": [int(first), int(last)]}:
            return end, Record("", t, b"", (first, last))
        case {"key": str(key), "t": int(t), "data": bytes(message)}:
            return end, Record(key, t, message)
    return None


def _runs_past_end(data: bytes, offset: int) -> bool:
    """Whether the record that starts at `offset` is unfinished: its header or payload is cut off."""
    if offset + HEADER.size > len(data):
        return True
    length, _ = HEADER.unpack_from(data, offset)
    return offset + HEADER.size + length > len(data)


def read_log(path: str | Path) -> tuple[list[Record], list[Damage]]:
    """Every intact record of a log, and the damaged stretches between them (none: a clean log).

    After a damaged record the reader tries each following byte until an intact record starts there
    (length, CRC and record map all check out), so one flipped bit costs one record, not the rest."""
    path = Path(path)
    data = path.read_bytes()
    if not data.startswith(MAGIC):
        raise ValueError(f"{path} is not a TSF recording (bad magic)")
    records: list[Record] = []
    damage: list[Damage] = []
    offset = len(MAGIC)
    while offset < len(data):
        found = _record_at(data, offset)
        if found is not None:
            offset, record = found
            records.append(record)
            continue
        resume = next((o for o in range(offset + 1, len(data)) if _record_at(data, o)), len(data))
        damage.append(Damage(offset, resume, resume == len(data) and _runs_past_end(data, offset)))
        offset = resume
    return records, damage


class LogWriter:
    """Appends records; reopening an existing log cuts a torn or corrupt tail first (damage before
    an intact record is left for readers to skip). Every record is written
    through to the OS at once (a killed process loses nothing it wrote); fsync runs at most every
    `sync_every` seconds and at close (what a power cut can cost)."""

    def __init__(self, path: str | Path, sync_every: float = 1.0) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.records = 0
        self.cut_bytes = 0
        self.last_records: list[Record] = []
        if self.path.exists() and self.path.stat().st_size >= len(MAGIC):
            self.last_records, damage = read_log(self.path)
            if damage and damage[-1].end == self.path.stat().st_size:
                self.cut_bytes = damage[-1].end - damage[-1].start
                with self.path.open("r+b") as handle:
                    handle.truncate(damage[-1].start)
            self._file = self.path.open("ab", buffering=0)
        else:
            self._file = self.path.open("wb", buffering=0)
            self._file.write(MAGIC)
        self.sync_every = sync_every
        self._synced = time.monotonic()

    def write(self, key: str, data: bytes, t: int | None = None) -> None:
        self._append(_payload(Record(key, time.time_ns() if t is None else t, bytes(data))))

    def write_gap(self, first: int, last: int) -> None:
        self._append(_payload(Record("", time.time_ns(), b"", (first, last))))

    def _append(self, payload: bytes) -> None:
        """Write the record whole: an unbuffered write may take part of it (a file size limit, a
        full disk); the rest is written again, so the OS's refusal raises at this record."""
        rest = memoryview(HEADER.pack(len(payload), zlib.crc32(payload)) + payload)
        while rest:
            rest = rest[self._file.write(rest) :]
        self.records += 1
        if time.monotonic() - self._synced >= self.sync_every:
            self.sync()

    def sync(self) -> None:
        os.fsync(self._file.fileno())
        self._synced = time.monotonic()

    def close(self) -> None:
        if not self._file.closed:
            try:
                self.sync()
            finally:  # closed even when the disk refuses the sync
                self._file.close()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _payload(record: Record) -> bytes:
    if record.gap is not None:
        return msgpack.packb({"t": record.t, "gap": list(record.gap)}, use_bin_type=True)
    return msgpack.packb({"key": record.key, "t": record.t, "data": record.data}, use_bin_type=True)


def make_way(path: Path, overwrite: bool) -> Path | None:
    """Free `path` for a new recording: an existing one is never appended to. Refused unless
    `overwrite`; then it, and its Parquet export beside it, are renamed `<name>.replaced-<n>` (the
    first free n). Returns where the old recording went, or None when there was none."""
    if not path.exists():
        return None
    if not overwrite:
        raise UsageError(
            "--match", path.stem, f"{path} exists; choose another id, or --overwrite to keep it aside"
        )
    n = 1
    while any(p.with_name(f"{p.name}.replaced-{n}").exists() for p in _with_export(path)):
        n += 1
    for old in _with_export(path):
        if old.exists():
            old.rename(old.with_name(f"{old.name}.replaced-{n}"))
    return path.with_name(f"{path.name}.replaced-{n}")


def _with_export(path: Path) -> tuple[Path, Path, Path]:
    return path, path.with_suffix(".tables"), path.with_suffix(".provenance.json")


class GapTracker:
    """Turns the stream of state frame numbers into explicit gaps: frames never seen."""

    def __init__(self, last: int = -1) -> None:
        self.last = last

    def see(self, frame: int) -> tuple[int, int] | None:
        gap = (self.last + 1, frame - 1) if frame > self.last + 1 else None
        self.last = max(self.last, frame)
        return gap
