"""The agent's pure core of a lockstep match's adaptive seat: a state is answered only once the
adapter has ruled on the frames before it.

The adapter scores the partner's frames in batches and rules on the last frame of each
(shared.game.scoring: 5, 11, 17, ...); its ruling says what the seat plays from the next frame. In
real time nothing waits for it (the sim owns the clock, and a slow adapter's switch plays late).
In a lockstep match the sim steps as fast as the seats answer, so an answer that did not wait
would play a switch at whatever frame the ruling happened to arrive: the recording would differ
run to run. So there the seat holds its answer to the state after a scoring frame until that
frame's ruling arrives, and a switch plays from the frame the in-process evaluation gives
(services/evaluation/evaluate.py). The wait is bounded (RULING_WAIT, below the sim's lockstep step
timeout): a late or dead adapter costs one wait, after which the gate stays open until its next
ruling comes.
"""

from __future__ import annotations

from shared.game import scoring
from shared.messages import State

RULING_WAIT = 0.5  # seconds a held answer waits for its ruling at most (the sim's step timeout is 1 s)


class Gate:
    """One adaptive seat's gate. `armed` once the match's Start says lockstep; until then (and in
    real time) every state is answered at once. Not locked: its shell calls it under one lock."""

    def __init__(self) -> None:
        self.armed = False
        self.ruled = -1  # the newest scoring frame ruled on
        self.waiting = True  # False after a wait ran out: the adapter is late or gone
        self.held: State | None = None  # the state whose answer waits for its ruling

    def offer(self, state: State) -> bool:
        """Whether `state` may be answered now; else it is held until `rule` or `expire` frees it."""
        before = state.frame - 1
        if not self.armed or not self.waiting or not scoring(before) or before <= self.ruled:
            return True
        self.held = state
        return False

    def rule(self, frame: int) -> State | None:
        """A ruling on scoring frame `frame` arrived: the held state it frees, if any. The gate
        waits again from now on (the adapter is back, if it was late)."""
        self.ruled, self.waiting = max(self.ruled, frame), True
        return self._free() if self.held is not None and self.held.frame - 1 <= self.ruled else None

    def expire(self, state: State) -> State | None:
        """The wait for `state`'s ruling ran out: `state` if it is still held (answer it now, with
        the policy it plays); the gate waits for no ruling until the next one arrives."""
        if self.held is not state:
            return None
        self.waiting = False
        return self._free()

    def _free(self) -> State | None:
        held, self.held = self.held, None
        return held
