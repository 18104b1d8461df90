"""The append-only log: exact read-back, torn tails detected and cut on reopen, CRC, gaps."""

from __future__ import annotations

import zlib
from pathlib import Path

import pytest

from services.recorder.log import HEADER, MAGIC, MAX_RECORD, GapTracker, LogWriter, Record, read_log


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


@pytest.fixture
def log(tmp_path: Path) -> tuple[Path, list[Record], list[int]]:
    path = tmp_path / "sub" / "m.tsflog"  # the writer makes the directory
    items = records(6)
    return path, items, write(path, items)


def test_read_back_exactly(log: tuple[Path, list[Record], list[int]]) -> None:
    path, items, _ = log
    got, clean = read_log(path)
    assert clean and without_times(got) == without_times(items)
    assert got[3].gap == (10, 12) and isinstance(got[3].gap, tuple)
    assert path.read_bytes().startswith(MAGIC)


def test_empty_log_is_clean(tmp_path: Path) -> None:
    path = tmp_path / "e.tsflog"
    LogWriter(path).close()
    assert path.read_bytes() == MAGIC and read_log(path) == ([], True)


@pytest.mark.parametrize("into", [1, 4, HEADER.size - 1, HEADER.size, HEADER.size + 1, -1])
def test_torn_tail(log: tuple[Path, list[Record], list[int]], into: int) -> None:
    """A cut `into` bytes into the last record (negative: from its end), header included."""
    path, items, starts = log
    size = path.stat().st_size
    torn = starts[-1] + into if into > 0 else size + into
    cut(path, torn)
    got, clean = read_log(path)
    assert not clean and without_times(got) == without_times(items[:-1])

    with LogWriter(path) as writer:
        assert writer.cut_bytes == torn - starts[-1] > 0
        assert without_times(writer.last_records) == without_times(items[:-1])
        writer.write("tsf/m/new", b"after the crash", 5)
    got, clean = read_log(path)
    assert clean and without_times(got) == without_times(
        [*items[:-1], Record("tsf/m/new", 5, b"after the crash")]
    )


def test_reopen_clean_log_appends(log: tuple[Path, list[Record], list[int]]) -> None:
    path, items, _ = log
    more = records(3, start=50)
    with LogWriter(path) as writer:
        assert writer.cut_bytes == 0 and len(writer.last_records) == len(items)
    write(path, more)
    got, clean = read_log(path)
    assert clean and without_times(got) == without_times(items + more)


def test_flipped_byte_in_last_payload(log: tuple[Path, list[Record], list[int]]) -> None:
    path, items, starts = log
    data = bytearray(path.read_bytes())
    data[-3] ^= 0x20
    path.write_bytes(bytes(data))
    got, clean = read_log(path)
    assert not clean and without_times(got) == without_times(items[:-1])
    with LogWriter(path) as writer:
        assert writer.cut_bytes == len(data) - starts[-1]
    assert read_log(path)[1]


def test_absurd_length_is_a_torn_tail(log: tuple[Path, list[Record], list[int]]) -> None:
    path, items, _ = log
    with path.open("ab") as handle:
        handle.write(HEADER.pack(MAX_RECORD + 1, 0) + b"x" * 16)
    got, clean = read_log(path)
    assert not clean and len(got) == len(items)


def test_crc_valid_garbage_payload_is_a_torn_tail(log: tuple[Path, list[Record], list[int]]) -> None:
    path, items, _ = log
    payload = b"\x93\x01\x02\x03"  # msgpack, but a list rather than a record map
    with path.open("ab") as handle:
        handle.write(HEADER.pack(len(payload), zlib.crc32(payload)) + payload)
    got, clean = read_log(path)
    assert not clean and len(got) == len(items)


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
