"""The labelling page in a real browser: 50 pairs answered by keyboard (ties, skips, an undo), the server
SIGKILLed and restarted midway, a second person on the same queue, and the export checked field by field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from icprl_lightning.commands.label import main as label_main
from icprl_lightning.data.store import load_dataset

VIEW, N = "darkroom_trajectories", 50
KEY = {"first": "1", "second": "2", "equal": "e", "skip": "s"}
ALICE = ["first", "second", "equal", "first", "skip", "second", "first", "second", "equal", "first"] * 5
BOB = ["second", "second", "first", "equal", "skip", "first", "first", "second"]
UNDONE = 10  # alice presses the wrong key at pair 10, takes it back with u, then answers ALICE[10]


def open_page(browser, url, who):
    page = browser.new_page()
    page.goto(f"{url}&annotator={who}")
    page.wait_for_selector("body[data-done]", state="attached")
    return page


def press(page, key, done):
    """Press ``key`` and wait until the server has acknowledged it (the page shows ``done`` answered)."""
    page.keyboard.press(key)
    page.wait_for_selector(f"body[data-done='{done}']", state="attached")


def test_fifty_pairs_by_keyboard_survive_a_kill(browser, servers, tmp_path):
    session = str(tmp_path / "session")
    server = servers("--session", session, "--view", VIEW, "--pairs", str(N), "--seed", "3")
    alice, bob = open_page(browser, server.url, "alice"), open_page(browser, server.url, "bob")
    assert alice.inner_text("#count") == f"0 / {N}"
    for i in range(25):
        if i == UNDONE:  # a wrong key, taken back
            press(alice, "2" if ALICE[i] != "second" else "1", i + 1)
            press(alice, "u", i)
        assert alice.get_attribute("body", "data-pair") == f"{VIEW}-{i:05d}"
        press(alice, KEY[ALICE[i]], i + 1)
        if i < len(BOB):  # bob answers between alice's answers, on the same queue
            press(bob, KEY[BOB[i]], i + 1)
    assert alice.inner_text("#count") == f"25 / {N}"
    assert alice.get_attribute("#fill", "style") == "width: 50%;"

    server.kill()  # SIGKILL: no shutdown code runs
    server = servers("--session", session)
    alice.goto(f"{server.url}&annotator=alice")  # the new server's token
    alice.wait_for_selector("body[data-done='25']", state="attached")
    assert alice.get_attribute("body", "data-pair") == f"{VIEW}-00025"
    for i in range(25, N):
        press(alice, KEY[ALICE[i]], i + 1)
    assert alice.inner_text("#question").startswith(f"All {N} pairs answered")
    server.stop()

    out = tmp_path / "export"
    assert label_main(["--session", session, "--export", str(out)]) == 0
    check_export(session, out)


def check_export(session, out):
    lines = [json.loads(x) for x in Path(session, "answers.jsonl").read_text().splitlines()]
    assert len(lines) == N + 2 + len(BOB)  # alice's 50 answers, the undone one and its undo; bob's 8
    assert len({x["nonce"] for x in lines}) == len(lines)
    answers = [json.loads(x) for x in (out / "answers.jsonl").read_text().splitlines()]
    expected = [("alice", i, label) for i, label in enumerate(ALICE)] + [("bob", i, b) for i, b in enumerate(BOB)]
    assert [(a["annotator"], a["row"], a["label"]) for a in answers] == expected
    for a in answers:
        assert a["pair"] == f"{VIEW}-{a['row']:05d}"
        assert isinstance(a["response_ms"], int) and 0 <= a["response_ms"] < 60_000
        assert a["time"].endswith("+00:00")
    with np.load(f"{session}/queue.npz") as z:
        queue = {k: z[k] for k in z.files}
    dataset = load_dataset(out / "dataset", verify=True)
    rows = {k: np.concatenate([dataset[s][k] for s in ("train", "val")]) for k in dataset["train"]}
    assert set(rows) == {"states_a", "actions_a", "states_b", "actions_b", "preferred", "task_index", "source_row"}
    decided = [a for a in answers if a["label"] in ("first", "second")]
    soft = [a for a in answers if a["label"] != "skip"]
    assert dataset.manifest["config"]["soft_labels"] is True
    assert sorted(rows["source_row"].tolist()) == sorted(answers.index(a) for a in soft)
    for j, line in enumerate(rows["source_row"]):
        a, q = answers[line], answers[line]["row"]
        for field in ("states_a", "actions_a", "states_b", "actions_b"):
            np.testing.assert_array_equal(rows[field][j], queue[field][q])
        assert rows["preferred"][j] == {"first": 1.0, "second": 0.0, "equal": 0.5}[a["label"]]
        assert rows["task_index"][j] == queue["task_index"][q] == a["task_index"]
    trl = pq.read_table(out / "trl_rows.parquet").to_pydict()
    assert len(trl["chosen"]) == len(decided)
    for a, chosen, rejected in zip(decided, trl["chosen"], trl["rejected"], strict=True):
        win, lose = ("_a", "_b") if a["label"] == "first" else ("_b", "_a")
        np.testing.assert_array_equal(chosen["states"], queue["states" + win][a["row"]])
        np.testing.assert_array_equal(rejected["actions"], queue["actions" + lose][a["row"]])
    with np.load(out / "imitation_pairs.npz") as z:
        assert z["label"].tolist() == [{"first": 1.0, "second": 0.0, "equal": 0.5}[a["label"]] for a in soft]
        np.testing.assert_array_equal(z["states_2"], queue["states_b"][[a["row"] for a in soft]])
    report = json.loads((out / "agreement.json").read_text())
    both = [i for i in range(len(BOB)) if {ALICE[i], BOB[i]} <= {"first", "second"}]
    same = sum(ALICE[i] == BOB[i] for i in both)
    assert report["alice"]["inter_annotator"]["bob"] == {"agreement": same / len(both), "pairs": len(both)}
    assert report["alice"]["equal"] == ALICE.count("equal") and report["bob"]["skip"] == BOB.count("skip")
