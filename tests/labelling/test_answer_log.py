"""The answer log: replayed on open, a torn last line dropped, a corrupt one refused, concurrent appends kept."""

from __future__ import annotations

import contextlib
import json
import threading

import pytest

from icprl_lightning.labelling.answer_log import AnswerLog, Refused

PAIRS = [f"p-{i:05d}" for i in range(30)]


def test_reopening_replays_answers_and_undos(tmp_path):
    log = AnswerLog.open(tmp_path / "a.jsonl", PAIRS)
    log.answer("ann", "p-00000", "first", "n0000000", 10)
    log.answer("ann", "p-00001", "equal", "n0000001", 10)
    log.undo("ann", "n0000002")
    log.answer("ann", "p-00001", "skip", "n0000003", 10)
    again = AnswerLog.open(tmp_path / "a.jsonl", PAIRS)
    assert [a["label"] for a in again.answers["ann"]] == ["first", "skip"]
    assert again.current("ann") == "p-00002"
    with pytest.raises(Refused):  # a nonce from before the restart is still a replay
        again.answer("ann", "p-00002", "first", "n0000001", 10)


def test_a_line_cut_short_by_a_kill_is_dropped(tmp_path):
    path = tmp_path / "a.jsonl"
    log = AnswerLog.open(path, PAIRS)
    log.answer("ann", "p-00000", "first", "n0000000", 10)
    whole = path.read_bytes()
    path.write_bytes(whole + b'{"event": "answer", "annotator": "ann", "pa')  # the kill hit mid-write
    again = AnswerLog.open(path, PAIRS)
    assert path.read_bytes() == whole
    assert again.current("ann") == "p-00001"
    again.answer("ann", "p-00001", "second", "n0000001", 10)
    assert [json.loads(x)["pair"] for x in path.read_text().splitlines()] == ["p-00000", "p-00001"]


def test_a_corrupt_line_is_an_error_naming_it(tmp_path):
    path = tmp_path / "a.jsonl"
    path.write_text('{"event": "answer"\nnot json\n')
    with pytest.raises(ValueError, match="line 1 is not JSON"):
        AnswerLog.open(path, PAIRS)


def test_concurrent_annotators_do_not_clash(tmp_path):
    """Four people answering at once from four threads: every answer on its own whole line, in each one's order."""
    log = AnswerLog.open(tmp_path / "a.jsonl", PAIRS)

    def person(who: str) -> None:
        for i, pair in enumerate(PAIRS):
            log.answer(who, pair, "first" if i % 2 else "second", f"{who}-{i:06d}", i)

    threads = [threading.Thread(target=person, args=(f"ann{k}",)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    again = AnswerLog.open(tmp_path / "a.jsonl", PAIRS)
    assert sorted(again.answers) == [f"ann{k}" for k in range(4)]
    for who, mine in again.answers.items():
        assert [a["pair"] for a in mine] == PAIRS
        assert [a["nonce"] for a in mine] == [f"{who}-{i:06d}" for i in range(len(PAIRS))]


def test_two_tabs_of_one_person_never_answer_a_pair_twice(tmp_path):
    """Threads racing to answer the same person's current pair: each pair is answered once, in order."""
    log = AnswerLog.open(tmp_path / "a.jsonl", PAIRS)
    counter = iter(range(10**6))

    def tab() -> None:
        while (pair := log.current("ann")) is not None:
            with contextlib.suppress(Refused):  # the other tab answered it first: a 409, the page shows the next
                log.answer("ann", pair, "first", f"nonce-{next(counter):06d}", 5)

    threads = [threading.Thread(target=tab) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    lines = [json.loads(x) for x in (tmp_path / "a.jsonl").read_text().splitlines()]
    assert [x["pair"] for x in lines] == PAIRS


def test_answers_an_agent_has_used_cannot_be_undone(tmp_path):
    log = AnswerLog.open(tmp_path / "a.jsonl", PAIRS)
    log.answer("ann", "p-00000", "first", "n0000000", 10)
    log.answer("ann", "p-00001", "second", "n0000001", 10)
    log.frozen["ann"] = 1  # the agent has read the first answer
    log.undo("ann", "n0000002")  # the second is still the person's to take back
    with pytest.raises(Refused, match="no answer to undo"):
        log.undo("ann", "n0000003")
    assert [a["pair"] for a in log.answers["ann"]] == ["p-00000"]
