"""Damaged recordings: a match recorded in-process, then cut, bit-flipped or duplicated; each test
asserts exactly what is recovered, what is reported missing, and what `tsf replay` says and exits."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import msgpack
import pytest

from services.commands.app import app
from services.commands.entry import run
from services.recorder.log import HEADER, MAGIC, Damage, LogWriter
from services.recorder.recording import load, replay
from services.recorder.recording_test import Script, record_match
from shared import keys
from shared.messages import Start, State, Summary, decode_any

FRAMES = 12
SCRIPT = Script(frames=FRAMES)


def spans(path: Path) -> list[tuple[int, int, object]]:
    """Each record of an intact log: (start, end, decoded message or None for a gap)."""
    data, out, offset = path.read_bytes(), [], len(MAGIC)
    while offset < len(data):
        length, _ = HEADER.unpack_from(data, offset)
        item = msgpack.unpackb(data[offset + HEADER.size : offset + HEADER.size + length])
        end = offset + HEADER.size + length
        out.append((offset, end, decode_any(item["data"]) if "data" in item else None))
        offset = end
    return out


@pytest.fixture(scope="module")
def original(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, list[tuple[int, int, object]]]:
    path = tmp_path_factory.mktemp("damage") / "m.tsflog"
    record_match(path, script=SCRIPT)
    return path.read_bytes(), spans(path)


def damaged(tmp_path: Path, data: bytes) -> Path:
    path = tmp_path / "m.tsflog"
    path.write_bytes(data)
    return path


@pytest.fixture
def replay_cli(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> Callable[..., tuple[int, str]]:
    """`tsf replay PATH OPTIONS...` in-process, as the command line runs it: (exit status, output)."""
    monkeypatch.setenv("COLUMNS", "400")  # rich wraps at 80 columns otherwise

    def replay_cli(path: Path, *options: str) -> tuple[int, str]:
        code = run(app, ["replay", str(path), *options])
        out, err = capsys.readouterr()
        return code, out + err

    return replay_cli


def test_the_intact_recording_is_complete(original, tmp_path: Path, replay_cli) -> None:  # noqa: ANN001
    recording = load(damaged(tmp_path, original[0]))
    assert recording.problems() == [] and recording.lost() == [] and replay(recording) == []
    code, output = replay_cli(recording.path)
    assert code == 0 and f"all {FRAMES + 1} states reproduce their hashes" in output


def test_a_cut_at_every_record_boundary(original, tmp_path: Path) -> None:  # noqa: ANN001
    """Everything before the cut is recovered; only the start and the summary can be missing."""
    data, records = original
    for k, (start, _, _) in enumerate(records):
        recording = load(damaged(tmp_path, data[:start]))
        before = [message for _, _, message in records[:k]]
        states = [m for m in before if isinstance(m, State)]
        assert recording.states == states and recording.damage == [] and recording.lost() == []
        last = states[-1].frame if states else None
        assert recording.problems() == [
            *(["no start record"] if k == 0 else []),
            f"no summary (last state: frame {last})",
        ], k
        assert recording.problems(allow_torn=True) == (["no start record"] if k == 0 else []), k


def test_a_cut_in_the_middle_of_each_record(original, tmp_path: Path) -> None:  # noqa: ANN001
    data, records = original
    for k, (start, end, _) in enumerate(records):
        cut = (start + end) // 2
        recording = load(damaged(tmp_path, data[:cut]))
        states = [m for _, _, m in records[:k] if isinstance(m, State)]
        assert recording.states == states and recording.damage == [Damage(start, cut, torn=True)], k
        assert recording.torn and recording.lost() == []
        assert recording.problems()[0] == f"torn tail at bytes {start}-{cut - 1}"
        assert recording.summary is None  # the last record


def test_a_torn_tail_fails_replay_unless_allowed(original, tmp_path: Path, replay_cli) -> None:  # noqa: ANN001
    data, records = original
    start, end, _ = next(r for r in records if isinstance(r[2], State) and r[2].frame == FRAMES // 2)
    path = damaged(tmp_path, data[: start + 5])
    code, output = replay_cli(path)
    assert code == 1 and "Traceback" not in output
    last = FRAMES // 2 - 1
    missing = f"torn tail at bytes {start}-{start + 4}; no summary (last state: frame {last})"
    assert output.strip() == f"tsf replay: {path}: incomplete: {missing}"
    code, output = replay_cli(path, "--allow-torn")
    assert code == 0 and f"all {last + 1} states reproduce their hashes" in output
    assert "its end is missing: --allow-torn" in output


def flipped(data: bytes, at: int, bit: int = 0x10) -> bytes:
    out = bytearray(data)
    out[at] ^= bit
    return bytes(out)


def test_a_flipped_bit_in_a_state_loses_that_frame_only(original, tmp_path: Path, replay_cli) -> None:  # noqa: ANN001
    data, records = original
    for frame in (0, 5, FRAMES):
        start, end, state = next(r for r in records if isinstance(r[2], State) and r[2].frame == frame)
        recording = load(damaged(tmp_path, flipped(data, end - 2)))
        assert recording.damage == [Damage(start, end)] and recording.lost() == [(frame, frame)]
        assert [s.frame for s in recording.states] == [f for f in range(FRAMES + 1) if f != frame]
        assert recording.summary is not None and recording.start is not None
        line = f"damaged at bytes {start}-{end - 1}; frames {frame} lost"
        assert recording.problems() == recording.problems(allow_torn=True) == line.split("; ")
        code, output = replay_cli(recording.path, "--allow-torn")
        assert (code, output.strip()) == (1, f"tsf replay: {recording.path}: incomplete: {line}")


def test_a_flipped_bit_in_the_start_or_summary_is_named(original, tmp_path: Path, replay_cli) -> None:  # noqa: ANN001
    data, records = original
    for kind, missing in ((Start, "no start record"), (Summary, f"no summary (last state: frame {FRAMES})")):
        start, end, _ = next(r for r in records if isinstance(r[2], kind))
        for at in (start, start + 5, end - 1):  # length, CRC, payload
            recording = load(damaged(tmp_path, flipped(data, at)))
            assert recording.damage == [Damage(start, end)] and len(recording.states) == FRAMES + 1
            assert recording.problems() == [f"damaged at bytes {start}-{end - 1}", missing]
            assert replay_cli(recording.path, "--allow-torn")[0] == 1  # damage is not a torn tail


def test_flipped_bits_in_several_records(original, tmp_path: Path) -> None:  # noqa: ANN001
    data, records = original
    hit = [r for r in records if isinstance(r[2], State) and r[2].frame in (3, 4, 9)]
    for _, end, _ in hit:
        data = flipped(data, end - 3, 0x01)
    recording = load(damaged(tmp_path, data))
    # frames 3 and 4 are not neighbours in the log (actions and events lie between): two stretches
    assert recording.damage == [Damage(start, end) for start, end, _ in hit]
    assert recording.lost() == [(3, 4), (9, 9)] and recording.summary is not None
    assert recording.problems()[-1] == "frames 3-4, 9 lost"


def test_duplicated_frames_are_reported_and_the_first_kept(original, tmp_path: Path, replay_cli) -> None:  # noqa: ANN001
    data, records = original
    again = [data[start:end] for start, end, m in records if isinstance(m, State) and m.frame in (2, 7)]
    recording = load(damaged(tmp_path, data + b"".join(again)))
    assert recording.duplicates == [2, 7] and [s.frame for s in recording.states] == list(range(FRAMES + 1))
    assert recording.problems() == ["frames 2, 7 recorded twice"] and replay(recording) == []
    assert replay_cli(recording.path)[0] == 1


def test_two_matches_in_one_log(original, tmp_path: Path) -> None:  # noqa: ANN001
    data, _ = original
    recording = load(damaged(tmp_path, data + data[len(MAGIC) :]))
    assert (recording.starts, recording.summaries) == (2, 2)
    assert recording.problems() == [
        "2 start records (more than one match)",
        "2 summaries (more than one match)",
        f"frames 0-{FRAMES} recorded twice",
    ]


def test_not_a_recording(tmp_path: Path, replay_cli) -> None:  # noqa: ANN001
    path = damaged(tmp_path, b"hello")
    code, output = replay_cli(path)
    assert (code, output.strip()) == (1, f"tsf replay: {path} is not a TSF recording (bad magic)")


@pytest.mark.parametrize("frame", [0, 5])
def test_a_stopped_matchs_fragment_is_never_complete(original, tmp_path: Path, frame: int) -> None:  # noqa: ANN001
    """A match stopped early writes a summary at its last frame: the recording is whole up to it,
    and still not the planned match."""
    data, records = original
    cut = next(end for _, end, m in records if isinstance(m, State) and m.frame == frame)
    path = damaged(tmp_path, data[:cut])
    summary = next(m for *_, m in records if isinstance(m, Summary))
    with LogWriter(path) as log:
        log.write(keys.summary(summary.match), dataclasses.replace(summary, frame=frame).encode())
    assert load(path).problems() == [f"stopped at frame {frame} of {FRAMES}"]
