"""Replaying a recording: the hash check, a video of rendered frames, and a live re-broadcast.

The check and the video re-simulate the match through the engine (recording.simulate), so a video
shows what the engine computes from the recorded inputs, and a state that the engine does not
reproduce is reported rather than drawn. The live re-broadcast puts the sim's own messages back on
the bus at the game's pace, so that the browser client can watch a past match as it watches a live
one.
"""

from __future__ import annotations

import dataclasses
import functools
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from services.recorder.log import read_log
from services.recorder.recording import Recording, simulate
from services.sim.engine import Game
from services.sim.render import BACKGROUND, render
from shared import keys
from shared.bus import BusConfig, session
from shared.errors import UsageError
from shared.game import ROLES, GameConfig
from shared.messages import AdapterStatus, GameEvent, Message, MessageError, Start, State, Summary, decode_any

VIDEO_FORMATS = (".gif", ".mp4")
CAPTION_LINES = 3  # score and time; both seats' policies; the adapter's estimate (when there is one)
TEXT = (235, 235, 235)
# What a watcher needs: the sim's messages and the adapter's view. Actions and policy switches are
# left out, so a re-broadcast can never drive a sim or an agent that listens on the same match id.
REPUBLISHED: dict[type[Message], object] = {
    Start: keys.start,
    State: keys.state,
    GameEvent: keys.event,
    Summary: keys.summary,
    AdapterStatus: keys.adapter,
}


def frames(
    recording: Recording, scale: float = 1.0, every: int = 1, captions: bool = True
) -> Iterator[np.ndarray]:
    """Rendered RGB frames of every `every`-th recorded state, each checked against its hash first;
    with `captions`, a band below the arena says what a reader needs (caption_lines)."""
    for state, game, lines in labelled(recording):
        if state.hash != game.state_hash():
            raise ValueError(f"{recording.path}: frame {state.frame} does not reproduce its recorded hash")
        if state.frame % every == 0:
            image = render(game, scale)
            yield caption(image, lines, scale) if captions else image


def labelled(recording: Recording) -> Iterator[tuple[State, Game, list[str]]]:
    """simulate() with each frame's caption: score, game time, both seats' policies (the start
    record's, then each switch or adapter status from its frame on) and the adapter's estimate."""
    config = GameConfig.from_dict(recording.start.config) if recording.start else GameConfig()
    seats = dict(recording.start.policies) if recording.start else {}
    changes = sorted([*recording.switches, *recording.adapter], key=lambda m: m.frame)
    estimate, due = "", 0
    for state, game in simulate(recording):
        while due < len(changes) and changes[due].frame <= state.frame:
            change = changes[due]
            seats[change.role] = change.policy
            if isinstance(change, AdapterStatus):
                outside = " (out of library)" if change.out_of_library else ""
                estimate = f"adapter ({change.role}): partner like {change.partner or '?'}{outside}"
            due += 1
        seconds, total = state.frame / config.fps, config.frames / config.fps
        lines = [
            f"kills {state.kills}   points {state.points}   time {seconds:5.1f} / {total:.0f} s",
            "   ".join(f"{role} {seats.get(role) or 'person'}" for role in ROLES),
        ]
        yield state, game, lines + ([estimate] if estimate else [])


def caption(image: np.ndarray, lines: list[str], scale: float = 1.0) -> np.ndarray:
    """The image with a band of text lines below it (Pillow's built-in font; no font files needed)."""
    from PIL import Image, ImageDraw

    size = max(10, round(16 * scale))
    font = _font(size)
    step = round(size * 1.3)
    height, width = image.shape[:2]
    band = Image.new("RGB", (width, step * CAPTION_LINES + size // 2), BACKGROUND)
    draw = ImageDraw.Draw(band)
    for i, line in enumerate(lines[:CAPTION_LINES]):
        draw.text((size // 2, size // 4 + i * step), line, fill=TEXT, font=font)
    return np.concatenate([image, np.asarray(band)], axis=0)


def write_video(recording: Recording, path: Path, scale: float = 1.0, every: int = 1) -> int:
    """Write the match as a GIF (Pillow) or an MP4 (H.264, the ffmpeg inside imageio-ffmpeg) at the
    game's speed, captioned (frames()); returns the number of frames written."""
    if path.suffix not in VIDEO_FORMATS:
        raise UsageError("--video", path, "not a video file name", (f"*{s}" for s in VIDEO_FORMATS))
    if recording.start is None:
        raise ValueError(f"{recording.path}: no start record, so the match cannot be replayed")
    fps = GameConfig.from_dict(recording.start.config).fps / every
    images = frames(recording, scale, every)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gif":
        from PIL import Image

        pictures = (Image.fromarray(image) for image in images)  # streamed: Pillow keeps only palettes
        first = next(pictures, None)
        if first is None:
            raise ValueError(f"{recording.path}: no states to draw")
        drawn = [1]

        def rest() -> Iterator:
            for picture in pictures:
                drawn[0] += 1
                yield picture

        first.save(path, save_all=True, append_images=rest(), duration=_gif_delay(fps), loop=0)
        return drawn[0]
    import imageio_ffmpeg

    count, writer = 0, None
    for image in images:
        image = _even(image)
        if writer is None:
            height, width = image.shape[:2]
            writer = imageio_ffmpeg.write_frames(
                str(path), (width, height), fps=fps, codec="libx264", macro_block_size=2, quality=7
            )
            writer.send(None)  # start the encoder
        writer.send(np.ascontiguousarray(image))
        count += 1
    if writer is None:
        raise ValueError(f"{recording.path}: no states to draw")
    writer.close()
    return count


@functools.cache
def _font(size: int):  # noqa: ANN202 - a Pillow font
    from PIL import ImageFont

    return ImageFont.load_default(size)


def _gif_delay(fps: float) -> int:
    """Milliseconds per GIF frame: GIF counts delays in hundredths of a second."""
    return 10 * max(1, round(100 / fps))


def _even(image: np.ndarray) -> np.ndarray:
    """Pad the image by one background row / column where needed: H.264 wants even sizes."""
    height, width = image.shape[:2]
    return np.pad(image, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge")


def schedule(path: Path, match: str | None = None, speed: float = 1.0) -> list[tuple[float, str, bytes]]:
    """The messages to re-broadcast, in recorded order: (seconds after the start, key, bytes).

    A message is due at its frame's game time (frame / fps / speed), whatever pace the match was
    recorded at, so a lockstep match plays back at real speed too. With `match`, every message is
    re-addressed to that match id (envelope and key)."""
    if speed <= 0:
        raise ValueError(f"speed must be positive, got {speed}")
    records, _ = read_log(path)
    fps = GameConfig().fps
    out = []
    for record in records:
        if record.gap is not None:
            continue
        try:
            message = decode_any(record.data)
        except MessageError:
            continue
        key_of = REPUBLISHED.get(type(message))
        if key_of is None:
            continue
        if isinstance(message, Start):
            fps = GameConfig.from_dict(message.config).fps
        data = record.data
        if match is not None and match != message.match:
            message = dataclasses.replace(message, match=match)
            data = message.encode()
        out.append((message.frame / fps / speed, key_of(message.match), data))
    return out


def republish(
    bus: BusConfig,
    path: Path,
    match: str | None = None,
    speed: float = 1.0,
    delay: float = 1.0,
    stop: threading.Event | None = None,
) -> int:
    """Put a recorded match back on the bus at the game's pace (see `schedule`), after `delay`
    seconds for watchers to link up; returns the number of messages sent."""
    stop = stop or threading.Event()
    plan = schedule(path, match, speed)
    sent = 0
    with session(bus) as z:
        if stop.wait(delay):
            return sent
        t0 = time.monotonic()
        for due, key, data in plan:
            if stop.wait(max(0.0, t0 + due - time.monotonic())):
                break
            z.put(key, data)
            sent += 1
    return sent
