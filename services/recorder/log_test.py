"""The append-only log: exact read-back, a cut or a flipped bit anywhere costing only what it hit, torn
tails cut on reopen, CRC, gaps."""

from __future__ import annotations

import resource
import zlib
from pathlib import Path

import pytest

from services.recorder.log import HEADER, MAGIC, MAX_RECORD, Damage, GapTracker, LogWriter, Record, read_log


def records(n: int, start: int = 0) -> list[Record]:
    """n data records with distinct keys, times and payloads (one empty), and a gap in the middle."""
    out = [Record(f"tsf/m/k{i}", 1_000 + i, bytes([i % 256]) * (i * 7)) for i in range(start, start + n)]
    out.insert(n // 2, Record("", 999, b"", (start + 10, start + 12)))
    return out


def write(path: Path, items: list[Record]) -> list[int]:
    """Append the records through a LogWriter; returns each record's start offset in the file."""
    starts = []
    with LogWriter(path) as writer:
        for item in items:
            starts.append(path.stat().st_size)
            if item.gap is None:
                writer.write(item.key, item.data, item.t)
            else:
                writer.write_gap(*item.gap)
        assert writer.records == len(items)
    return starts


def without_times(items: list[Record]) -> list[Record]:
    """Gap records carry the time they were written: compare them by their frames only."""
    return [Record("", 0, b"", r.gap) if r.gap else r for r in items]


def cut(path: Path, size: int) -> None:
    with path.open("r+b") as handle:
        handle.truncate(size)


Log = tuple[Path, list[Record], list[int]]  # the file, its records, and where each starts


@pytest.fixture
def log(tmp_path: Path) -> Log:
    path = tmp_path / "sub" / "m.tsflog"  # the writer makes the directory
    items = records(6)
    return path, items, write(path, items)


def test_read_back_exactly(log: Log) -> None:
    path, items, _ = log
    got, damage = read_log(path)
    assert damage == [] and without_times(got) == without_times(items)
    assert got[3].gap == (10, 12) and isinstance(got[3].gap, tuple)
    assert path.read_bytes().startswith(MAGIC)


def test_empty_log_is_clean(tmp_path: Path) -> None:
    path = tmp_path / "e.tsflog"
    LogWriter(path).close()
    assert path.read_bytes() == MAGIC and read_log(path) == ([], [])


def test_a_cut_anywhere_keeps_every_record_before_it(log: Log) -> None:
    """Cut at every byte: the records that end before the cut, and a torn tail unless the cut is on a
    record boundary."""
    path, items, starts = log
    whole = path.read_bytes()
    ends = [*starts[1:], len(whole)]
    for size in range(len(MAGIC), len(whole) + 1):
        path.write_bytes(whole[:size])
        got, damage = read_log(path)
        kept = sum(end <= size for end in ends)
        assert without_times(got) == without_times(items[:kept]), size
        boundary = ends[kept - 1] if kept else len(MAGIC)
        assert damage == ([] if size == boundary else [Damage(boundary, size, torn=True)]), size


@pytest.mark.parametrize("into", [1, 4, HEADER.size - 1, HEADER.size, HEADER.size + 1, -1])
def test_torn_tail_is_cut_on_reopen(log: Log, into: int) -> None:
    """A cut `into` bytes into the last record (negative: from its end), header included."""
    path, items, starts = log
    size = path.stat().st_size
    torn = starts[-1] + into if into > 0 else size + into
    cut(path, torn)
    with LogWriter(path) as writer:
        assert writer.cut_bytes == torn - starts[-1] > 0
        assert without_times(writer.last_records) == without_times(items[:-1])
        writer.write("tsf/m/new", b"after the crash", 5)
    got, damage = read_log(path)
    assert damage == [] and without_times(got) == without_times(
        [*items[:-1], Record("tsf/m/new", 5, b"after the crash")]
    )


def test_reopen_clean_log_appends(log: Log) -> None:
    path, items, _ = log
    more = records(3, start=50)
    with LogWriter(path) as writer:
        assert writer.cut_bytes == 0 and len(writer.last_records) == len(items)
    write(path, more)
    got, damage = read_log(path)
    assert damage == [] and without_times(got) == without_times(items + more)


FLIPS = [(0, 0x01), (0, 0x80), (3, 0x01), (4, 0x10), (7, 0x80), (HEADER.size, 0x01), (-1, 0x04)]


@pytest.mark.parametrize(("at", "bit"), FLIPS, ids=[f"byte{a}-bit{b:#x}" for a, b in FLIPS])
def test_one_flipped_bit_costs_one_record(log: Log, at: int, bit: int) -> None:
    """A bit flipped in the length, the CRC or the payload of each record in turn: the reader skips
    exactly that record's bytes and reads on."""
    path, items, starts = log
    whole = path.read_bytes()
    ends = [*starts[1:], len(whole)]
    for k, (start, end) in enumerate(zip(starts, ends, strict=True)):
        data = bytearray(whole)
        data[start + at if at >= 0 else end + at] ^= bit
        path.write_bytes(bytes(data))
        got, damage = read_log(path)
        assert without_times(got) == without_times(items[:k] + items[k + 1 :]), k
        length = HEADER.unpack_from(data, start)[0]
        torn = end == len(data) and start + HEADER.size + length > len(data)  # the last record now runs past
        assert damage == [Damage(start, end, torn)], k


def test_a_damaged_record_inside_the_log_is_kept_on_reopen(log: Log) -> None:
    """Only a damaged end is cut: a damaged record before intact ones stays for readers to skip."""
    path, items, starts = log
    data = bytearray(path.read_bytes())
    data[starts[2] + HEADER.size] ^= 0x01
    path.write_bytes(bytes(data))
    with LogWriter(path) as writer:
        assert writer.cut_bytes == 0
        writer.write("tsf/m/new", b"more", 5)
    got, damage = read_log(path)
    assert damage == [Damage(starts[2], starts[3])]
    assert without_times(got) == without_times([*items[:2], *items[3:], Record("tsf/m/new", 5, b"more")])


def test_corrupt_last_record_is_cut_on_reopen(log: Log) -> None:
    path, items, starts = log
    data = bytearray(path.read_bytes())
    data[-3] ^= 0x20
    path.write_bytes(bytes(data))
    assert read_log(path)[1] == [Damage(starts[-1], len(data))]  # complete but corrupt: not torn
    with LogWriter(path) as writer:
        assert writer.cut_bytes == len(data) - starts[-1]
    assert read_log(path)[1] == []


def test_absurd_length_is_a_torn_tail(log: Log) -> None:
    path, items, _ = log
    size = path.stat().st_size
    with path.open("ab") as handle:
        handle.write(HEADER.pack(MAX_RECORD + 1, 0) + b"x" * 16)
    got, damage = read_log(path)
    assert damage == [Damage(size, size + HEADER.size + 16, torn=True)] and len(got) == len(items)


@pytest.mark.parametrize(
    "payload",
    [b"\x93\x01\x02\x03", b"\x82\xa1t\x01\xa3gap\x01", b"\x83\xa3key\x01\xa1t\x01\xa4data\xc4\x00"],
    ids=["list", "gap-not-a-range", "key-not-text"],
)
def test_crc_valid_garbage_payload_is_damage(log: Log, payload: bytes) -> None:
    """msgpack with a good CRC, but not a record map: damage, not a record."""
    path, items, _ = log
    size = path.stat().st_size
    with path.open("ab") as handle:
        handle.write(HEADER.pack(len(payload), zlib.crc32(payload)) + payload)
    got, damage = read_log(path)
    assert damage == [Damage(size, size + HEADER.size + len(payload))] and len(got) == len(items)


@pytest.mark.parametrize("head", [b"TSFLOG2\n", b"not a log at all", b"\x00" * 8])
def test_bad_magic(tmp_path: Path, head: bytes) -> None:
    path = tmp_path / "bad.tsflog"
    path.write_bytes(head)
    with pytest.raises(ValueError, match="bad magic"):
        read_log(path)
    with pytest.raises(ValueError, match="bad magic"):
        LogWriter(path)
    assert path.read_bytes() == head  # never overwritten


def test_gap_tracker() -> None:
    gaps = GapTracker()
    seen = [gaps.see(frame) for frame in (0, 1, 4, 3, 4, 5, 10, 11)]
    assert seen == [None, None, (2, 3), None, None, None, (6, 9), None]
    assert gaps.last == 11
    assert GapTracker().see(3) == (0, 2)  # the first frames were missed
    resumed = GapTracker(last=5)  # a restarted recorder resumes after its last state
    assert resumed.see(5) is None and resumed.see(7) == (6, 6)


def test_a_record_the_os_takes_in_part_raises_at_that_record(tmp_path: Path) -> None:
    """Past a file size limit the OS writes part of a record and returns the count: the writer
    writes the rest, so the record that does not fit raises (EFBIG), and is not left torn for a
    later record to find or a close to hide. (Python ignores SIGXFSZ; the limit binds root too.)"""
    writer = LogWriter(tmp_path / "full.tsflog")
    writer.write("tsf/m/state", bytes(40))
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (tmp_path.joinpath("full.tsflog").stat().st_size + 100, hard))
    try:
        with pytest.raises(OSError, match="File too large"):
            writer.write("tsf/m/state", bytes(200))
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    writer.close()
    records, damage = read_log(tmp_path / "full.tsflog")
    assert len(records) == 1 and damage[0].torn
