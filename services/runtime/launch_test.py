"""The launchers' last check: a match whose processes all exited 0 is still a failure when its
recording is missing or incomplete (once, a recorder cut off under load left an 8-byte log)."""

from __future__ import annotations

import pytest

from services.recorder.log import MAGIC
from services.recorder.recording_test import record_match
from services.runtime.launch import Incomplete, read_back, read_recording


def problems(path):  # noqa: ANN001, ANN201 - a Path; its problems
    return read_recording(path)[1]


def test_a_complete_recording_has_no_problems_and_a_missing_or_cut_one_does(tmp_path):
    path = tmp_path / "m.tsflog"
    assert read_recording(path) == (None, ["no such file"])
    path.write_bytes(MAGIC)  # a recorder that started but recorded nothing
    assert problems(path) == ["no start record", "no summary (last state: frame None)"]
    path.write_bytes(b"TSF")  # cut inside its magic
    assert read_recording(path) == (None, [f"{path} is not a TSF recording (bad magic)"])
    path.unlink()
    record_match(path)
    assert problems(path) == []
    assert read_back(path, "m").summary is not None
    whole = path.read_bytes()
    path.write_bytes(whole[:-5])  # its last record (the summary) cut short
    found = problems(path)
    assert found[0].startswith("torn tail at bytes") and found[-1].startswith("no summary (last state")
    with pytest.raises(Incomplete, match=f"match m: its recording {path} is incomplete: torn tail") as error:
        read_back(path, "m")
    assert error.value.problems == found
