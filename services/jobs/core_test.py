"""The job system's bookkeeping and result checks, without a bus."""

from __future__ import annotations

from services.jobs.core import Coordinator, Hashes, Spec, check, journal_line, read_journal, spec

OURS = Hashes("0123456789abcdef", "fedcba9876543210")


def specs(n: int) -> list[Spec]:
    return [spec(f"B4-S4-{i}-1", "table", {"bait": "B4", "shooter": "S4", "seeds": [i]}, 1) for i in range(n)]


def make_coordinator(n: int = 4, per_worker: int = 1) -> Coordinator:
    return Coordinator(specs(n), {}, per_worker)


def test_a_dead_workers_job_goes_to_another():
    c = make_coordinator()
    c.worker_up("a")
    c.worker_up("b")
    sent = dict(c.assignments(0.0, 60))
    assert set(sent) == {"a", "b"}
    c.worker_down("a")
    c.worker_up("c")
    resent = dict(c.assignments(1.0, 60))
    assert resent["c"].id == sent["a"].id


def test_each_job_counts_once():
    c = make_coordinator(1)
    c.worker_up("a")
    c.worker_up("b")
    ((worker, job),) = c.assignments(0.0, 60)
    c.worker_down(worker)  # presumed dead, yet its result arrives
    ((other, again),) = c.assignments(1.0, 60)
    assert again == job and other != worker
    assert c.result(worker, job.id, [1.0]) is True
    assert c.result(other, job.id, [2.0]) is False
    assert c.done == {job.id: [1.0]} and c.duplicates == 1 and c.finished


def test_a_slow_job_is_sent_again_and_a_failing_worker_gets_nothing_more():
    c = make_coordinator(2)
    c.worker_up("a")
    ((_, job),) = c.assignments(0.0, timeout=10)
    c.worker_up("b")
    resent = dict(c.assignments(11.0, timeout=10))
    assert resent == {"b": job}
    assert c.result("a", job.id, [3.0]) and "a" in c.idle  # the slow worker answers after all
    c.failed("b", job.id)
    assert "b" not in c.idle and all(w != "b" for w, _ in c.assignments(12.0, 10))
    c.worker_up("b")  # its token comes and goes: still barred for this run
    assert "b" not in c.idle and "b" not in c.live


def test_idle_workers_share_the_waiting_jobs_in_batches():
    c = make_coordinator(7, per_worker=3)
    c.worker_up("a")
    c.worker_up("b")
    sent = c.assignments(0.0, 60)
    assert [w for w, _ in sent] == ["a"] * 3 + ["b"] * 3  # 3 each, not 4 and 3: the cap holds
    c.worker_down("a")
    c.worker_up("c")
    resent = c.assignments(1.0, 60)
    assert [j for w, j in resent if w == "c"] == [j for w, j in sent if w == "a"]  # a's batch, whole
    for worker, job in sent[3:]:
        c.result(worker, job.id, [1.0])
    assert "b" in c.idle and [j.id for _, j in c.assignments(2.0, 60)] == [specs(7)[6].id]


def test_a_job_id_names_what_it_computes():
    a, b = specs(2)
    assert a.id.startswith("B4-S4-0-1.") and a.id != b.id
    assert spec("x", "team", {"games": [["B1", "S1", 0]]}, 1).id != spec("x", "team", {"games": []}, 0).id


def test_results_are_checked_for_job_hashes_and_size():
    (job,) = specs(1)
    assert check(job, [2.0], OURS.library, OURS.config, OURS) == ""
    assert "library/rules" in check(job, [2.0], "0" * 16, OURS.config, OURS)
    assert "library/rules" in check(job, [2.0], OURS.library, "0" * 16, OURS)
    assert "values" in check(job, [2.0, 3.0], OURS.library, OURS.config, OURS)
    assert "no such job" in check(None, [2.0], OURS.library, OURS.config, OURS)


def test_journal_resumes_refuses_torn_and_stale_lines_and_passes_over_other_runs(tmp_path):
    todo = specs(3)
    path = tmp_path / "t.journal"
    planted = journal_line(todo[1].id, [99.0], Hashes("badbadbadbadbad0", OURS.config))  # the line
    path.write_text(
        journal_line(todo[0].id, [2.0], OURS)
        + planted
        + journal_line("B9-S9-0-1.0000000000", [1.0], OURS)
        + journal_line(todo[2].id, [1.0, 2.0], OURS)
        + '{"job": "B4-S4-1-1.'
    )
    read = read_journal(path, {job.id: job for job in todo}, OURS)
    assert read.done == {todo[0].id: [2.0]}
    assert len(read.refused) == 3 and "library/rules badbadbadbadbad0" in read.refused[0]
    c = Coordinator(todo, read.done)
    assert [j.id for j in c.waiting] == [todo[1].id, todo[2].id]
