"""Replay: videos of re-simulated frames and the re-broadcast schedule, on a match recorded in-process
as the recorder writes it (recording_test.record_match)."""

from __future__ import annotations

from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
from PIL import Image

from services.recorder.recording import load
from services.recorder.recording_test import FRAMES, SWITCH_AT, M, record_match
from services.recorder.replay import caption, frames, labelled, schedule, write_video
from services.sim.engine import Game
from services.sim.render import render
from shared import keys
from shared.game import GameConfig
from shared.messages import Action, GameEvent, PolicySwitch, Start, State, Summary, decode_any


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("replay") / f"{M}.tsflog"
    record_match(path)
    return path


def test_frames_are_the_engine_pictures(recorded: Path) -> None:
    pictures = list(frames(load(recorded), every=10, captions=False))
    assert len(pictures) == FRAMES // 10 + 1
    first = render(Game(GameConfig(frames=FRAMES), 5))
    assert np.array_equal(pictures[0], first)
    assert not np.array_equal(pictures[-1], first)


def test_each_frame_is_captioned_with_score_time_policies_and_the_adapters_estimate(recorded: Path) -> None:
    by_frame = {state.frame: (state, lines) for state, _, lines in labelled(load(recorded))}
    state, lines = by_frame[0]
    assert lines == [f"kills 0   points {state.points}   time   0.0 / 2 s", "bait circle   shooter mirror"]
    state, lines = by_frame[SWITCH_AT]  # the bait switched, the adapter put S5 in the shooter's seat
    assert lines[0] == f"kills {state.kills}   points {state.points}   time   1.0 / 2 s"
    assert lines[1:] == ["bait idle   shooter S5", "adapter (shooter): partner like B5"]
    pictures = list(frames(load(recorded), every=SWITCH_AT))
    arena = render(Game(GameConfig(frames=FRAMES), 5))
    assert np.array_equal(pictures[0][: arena.shape[0]], arena)  # the arena as it was, text below it
    bands = [p[arena.shape[0] :] for p in pictures[:2]]
    assert all(len(np.unique(band.reshape(-1, 3), axis=0)) > 5 for band in bands)  # text, not blank
    assert not np.array_equal(*bands)


def test_tampered_frame_is_not_drawn(tmp_path: Path) -> None:
    path = tmp_path / "t.tsflog"
    record_match(path, tamper=17)
    with pytest.raises(ValueError, match="frame 17 does not reproduce"):
        list(frames(load(path)))


def test_gif(recorded: Path, tmp_path: Path) -> None:
    out = tmp_path / "m.gif"
    assert write_video(load(recorded), out, scale=0.5, every=2) == FRAMES // 2 + 1
    with Image.open(out) as gif:
        assert gif.n_frames == FRAMES // 2 + 1
        assert gif.info["duration"] == 70  # 1/15 s, in GIF's hundredths
        assert gif.size == caption(render(Game(GameConfig(), 0), 0.5), [], 0.5).shape[1::-1]


def test_mp4(recorded: Path, tmp_path: Path) -> None:
    out = tmp_path / "m.mp4"
    assert write_video(load(recorded), out, scale=0.5) == FRAMES + 1
    count, seconds = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert count == FRAMES + 1 and seconds == pytest.approx((FRAMES + 1) / 30, abs=0.05)


def test_video_format_is_checked(recorded: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"--video .*m.avi: not a video file name; valid: \*.gif, \*.mp4"):
        write_video(load(recorded), tmp_path / "m.avi")


def test_schedule_readdresses_the_watchable_messages(recorded: Path) -> None:
    recording = load(recorded)
    plan = schedule(recorded, match="again", speed=2.0)
    messages = [(due, key, decode_any(data)) for due, key, data in plan]
    assert all(m.match == "again" and key.startswith("tsf/again/") for _, key, m in messages)
    assert not any(isinstance(m, Action | PolicySwitch) for _, _, m in messages)
    states = [(due, m) for due, _, m in messages if isinstance(m, State)]
    assert [m.hash for _, m in states] == [s.hash for s in recording.states]
    assert [due for due, _ in states] == pytest.approx([s.frame / 60 for s in recording.states])
    assert isinstance(messages[0][2], Start) and isinstance(messages[-1][2], Summary)
    assert sum(isinstance(m, GameEvent) for _, _, m in messages) == len(recording.events)
    assert [key for _, key, m in messages if isinstance(m, State)][0] == keys.state("again")
    as_recorded = [data for _, key, data in schedule(recorded) if key == keys.state(M)]
    assert as_recorded == [s.encode() for s in recording.states]
