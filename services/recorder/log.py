"""The recording: an append-only, crash-safe log of everything a match put on the bus.

File layout (docs/recording.md): the 8-byte magic `TSFLOG1\\n`, then records, each framed as

    u32 little-endian payload length | u32 little-endian CRC-32 of the payload | payload

The payload is a msgpack map: {"key": bus key, "t": receive time (ns since the epoch),
"data": the message bytes exactly as received} or, for frames the recorder did not see,
{"gap": [first missing frame, last missing frame]}. A crash can only tear the last record; opening
the log for appending detects a torn or corrupt tail by its length and checksum and cuts it off.
"""

from __future__ import annotations

import os
import struct
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgpack

MAGIC = b"TSFLOG1\n"
HEADER = struct.Struct("<II")
MAX_RECORD = 1 << 20


@dataclass(frozen=True)
class Record:
    key: str  # "" for a gap record
    t: int
    data: bytes  # the message as it was on the bus
    gap: tuple[int, int] | None = None


def _scan(handle) -> Iterator[tuple[int, Record]]:  # noqa: ANN001 - a binary file
    """Yield (end offset, record) for every intact record from the current position; stop at the
    first torn or corrupt one."""
    while True:
        header = handle.read(HEADER.size)
        if len(header) < HEADER.size:
            return
        length, crc = HEADER.unpack(header)
        if length > MAX_RECORD:
            return
        payload = handle.read(length)
        if len(payload) < length or zlib.crc32(payload) != crc:
            return
        try:
            item = msgpack.unpackb(payload, raw=False)
            record = (
                Record("", item["t"], b"", tuple(item["gap"]))
                if "gap" in item
                else Record(item["key"], item["t"], item["data"])
            )
        except (ValueError, KeyError, TypeError):
            return
        yield handle.tell(), record


def read_log(path: str | Path) -> tuple[list[Record], bool]:
    """All intact records of a log, and whether it ended cleanly (False: a torn or corrupt tail)."""
    records, good_end, size = _read(Path(path))
    return records, good_end == size


def _read(path: Path) -> tuple[list[Record], int, int]:
    with path.open("rb") as handle:
        if handle.read(len(MAGIC)) != MAGIC:
            raise ValueError(f"{path} is not a TSF recording (bad magic)")
        good_end, records = len(MAGIC), []
        for good_end, record in _scan(handle):  # noqa: B007 - the last intact end is kept
            records.append(record)
    return records, good_end, path.stat().st_size


class LogWriter:
    """Appends records; reopening an existing log cuts a torn tail first. Every record is written
    through to the OS at once (a killed process loses nothing it wrote); fsync runs at most every
    `sync_every` seconds and at close (what a power cut can cost)."""

    def __init__(self, path: str | Path, sync_every: float = 1.0) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.records = 0
        self.cut_bytes = 0
        self.last_records: list[Record] = []
        if self.path.exists() and self.path.stat().st_size >= len(MAGIC):
            self.last_records, good, size = _read(self.path)
            self.cut_bytes = size - good
            with self.path.open("r+b") as handle:
                handle.truncate(good)
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
        self._file.write(HEADER.pack(len(payload), zlib.crc32(payload)) + payload)
        self.records += 1
        if time.monotonic() - self._synced >= self.sync_every:
            self.sync()

    def sync(self) -> None:
        os.fsync(self._file.fileno())
        self._synced = time.monotonic()

    def close(self) -> None:
        if not self._file.closed:
            self.sync()
            self._file.close()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _payload(record: Record) -> bytes:
    if record.gap is not None:
        return msgpack.packb({"t": record.t, "gap": list(record.gap)}, use_bin_type=True)
    return msgpack.packb({"key": record.key, "t": record.t, "data": record.data}, use_bin_type=True)


class GapTracker:
    """Turns the stream of state frame numbers into explicit gaps: frames never seen."""

    def __init__(self, last: int = -1) -> None:
        self.last = last

    def see(self, frame: int) -> tuple[int, int] | None:
        gap = (self.last + 1, frame - 1) if frame > self.last + 1 else None
        self.last = max(self.last, frame)
        return gap
