"""A pooled match's end: the launcher waits for a recorder behind for as long as its log grows."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

from services.runtime import pool


def test_a_recorder_behind_is_waited_for_while_its_log_grows_and_given_up_once_not(tmp_path, monkeypatch):
    monkeypatch.setattr(pool, "CLOSE", 2.0)
    log, closed = tmp_path / "m.tsflog", threading.Event()

    def late_recorder(writes: int, then_close: bool) -> None:
        """Appends a record every 0.05 s (well within CLOSE), `writes` times, then closes the log or not."""
        for _ in range(writes):
            with log.open("ab") as file:
                file.write(b"x" * 100)
            time.sleep(0.05)
        if then_close:
            closed.set()

    for writes, then_close in ((80, True), (10, False)):  # 4 s of writing, twice CLOSE; then 0.5 s
        closed.clear()
        log.write_bytes(b"")
        writer = threading.Thread(target=late_recorder, args=(writes, then_close))
        writer.start()
        pool._wait_closed(SimpleNamespace(closed=closed), log)
        assert closed.is_set() == then_close, "waited for the close while the log grew (cut off at CLOSE)"
        writer.join()
