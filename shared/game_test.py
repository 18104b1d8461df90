"""The adapter's scoring frames: batches of SCORE_FRAMES frames of the match, each ruled on its last."""

from __future__ import annotations

from shared.game import SCORE_FRAMES, ruled_at, scoring


def test_a_choice_plays_from_the_frame_after_its_batchs_last() -> None:
    assert SCORE_FRAMES == 6
    assert [f for f in range(20) if scoring(f)] == [5, 11, 17]
    assert [ruled_at(f) for f in (0, 5, 6, 11, 149, 188)] == [5, 5, 11, 11, 149, 191]
    assert all(scoring(ruled_at(f)) and 0 <= ruled_at(f) - f < SCORE_FRAMES for f in range(100))
