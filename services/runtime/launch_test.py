"""run_match's last check: a match whose processes all exited 0 is still a Failure when its
recording is missing or incomplete (once, a recorder cut off under load left an 8-byte log)."""

from __future__ import annotations

from services.recorder.log import MAGIC
from services.recorder.recording_test import record_match
from services.runtime.launch import recording_problems


def test_a_complete_recording_has_no_problems_and_a_missing_or_cut_one_does(tmp_path):
    path = tmp_path / "m.tsflog"
    assert recording_problems(path) == ["no such file"]
    path.write_bytes(MAGIC)  # a recorder that started but recorded nothing
    assert recording_problems(path) == ["no start record", "no summary (last state: frame None)"]
    path.write_bytes(b"TSF")  # cut inside its magic
    assert recording_problems(path) == [f"{path} is not a TSF recording (bad magic)"]
    path.unlink()
    record_match(path)
    assert recording_problems(path) == []
    whole = path.read_bytes()
    path.write_bytes(whole[:-5])  # its last record (the summary) cut short
    problems = recording_problems(path)
    assert problems[0].startswith("torn tail at bytes") and problems[-1].startswith("no summary (last state")
