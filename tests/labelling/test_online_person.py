"""A person teaches the online agent in context through the page (``labelling/online.py``): a scripted
Bradley–Terry person at τ = 1 answers through the page's HTTP API, and a person at the keyboard in Chromium."""

from __future__ import annotations

import json
import threading
import time

import httpx
import numpy as np
import torch
import yaml
from factories import save_untrained

from icprl_lightning.commands import main
from icprl_lightning.contexts import ActionSpec
from icprl_lightning.data.settings.trajectory_pairs import label_trajectory_pairs
from icprl_lightning.evaluation import online_mdp
from icprl_lightning.labelling.online import BrowserAnnotator
from icprl_lightning.labelling.pairs import DarkRoomTrajectories
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.policy import InContextPolicy
from icprl_lightning.online import OnlineAgent

MOVES = np.array([[0, 1], [0, -1], [-1, 0], [1, 0], [0, 0]])  # up, down, left, right, stay (DarkRoom's)


def agent(max_context: int) -> OnlineAgent:
    torch.manual_seed(0)
    policy = InContextPolicy("step_preference", 2, ActionSpec(discrete=True, size=5),
                             backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2), max_context=max_context).eval()
    return OnlineAgent(policy, seed=0)


def bradley_terry_person(url: str, stop: threading.Event, rng: np.random.Generator, tau: float = 1.0) -> None:
    """Reads each question off the page's API as a person would see it (cell, goal, two moves), judges a move by
    how close it leads to the goal, answers ~ Bradley–Terry at temperature τ after a short (scaled) delay."""
    origin, query = url.split("/?")
    token = dict(x.split("=") for x in query.split("&"))["token"]
    with httpx.Client(base_url=origin) as client:
        while not stop.is_set():
            try:
                shown = client.get(f"/api/pair?token={token}&annotator=person").json()
            except httpx.TransportError:  # the run is over and its page closed: the person leaves
                return
            if shown.get("done"):
                time.sleep(0.005)
                continue
            goal = np.array(shown["goal"])
            if shown["view"] == "darkroom_trajectories":  # the steps each episode spent on the goal
                u = [np.all(np.array(shown[k]) == goal, axis=1).sum() for k in ("first", "second")]
            else:  # how close each move leads to the goal
                u = [-np.abs(np.clip(np.array(shown["cell"]) + MOVES[shown[k]], 0, 9) - goal).sum()
                     for k in ("first", "second")]
            label = "first" if rng.random() < 1 / (1 + np.exp(-(u[0] - u[1]) / tau)) else "second"
            time.sleep(rng.uniform(0.0, 0.004))  # a person's seconds, scaled down
            client.post(f"/api/answer?token={token}", json={"annotator": "person", "pair": shown["pair"],
                                                            "label": label, "nonce": f"bt{rng.integers(1 << 60):x}",
                                                            "response_ms": int(rng.integers(400, 4000))})


def test_a_scripted_person_answers_the_online_agent_through_the_page(tiny_ipref, tmp_path):
    suite = tiny_ipref.held_out("rollouts")[0]
    person = BrowserAnnotator(str(tmp_path / "online"))
    url, stop = person.start(), threading.Event()
    answering = threading.Thread(target=bradley_terry_person, args=(url, stop, np.random.default_rng(0)))
    answering.start()
    played = agent(max_context=6)
    try:
        result = online_mdp.online_episodes(played, tiny_ipref.family, suite, person, episodes=2, seed=0)
    finally:
        stop.set()
        answering.join()
        person.stop()
    b = len(suite.task_index)
    assert result["return"].shape == (3, b) and result["context_length"].tolist() == [3, 6, 6]
    asked = [json.loads(x) for x in (tmp_path / "online" / "asked.jsonl").read_text().splitlines()]
    log = [json.loads(x) for x in (tmp_path / "online" / "answers.jsonl").read_text().splitlines()]
    assert len(asked) == len(log) == 6 * b and [x["pair"] for x in log] == [x["pair"] for x in asked]
    context = played.context
    for k, (question, answer) in enumerate(zip(asked, log, strict=True)):
        i, step = question["task"], k // b  # the k-th question: task i's comparison number `step`
        assert i == k % b and len(question["context"]) == step
        assert (question["first"], question["second"]) == (int(context.actions[i, step]),
                                                           int(context.alt_actions[i, step]))
        assert context.preferred[i, step] == (answer["label"] == "first")  # the person's answer is the token
        assert question["cell"] == context.states[i, step].tolist()
    second_episode = [q for q in asked[3 * b:] if q["task"] == 0]
    assert all(len(q["path"]) >= 1 and isinstance(q["return"], float) for q in second_episode)


def test_a_person_at_the_keyboard_teaches_the_agent(browser, tiny_ipref, tmp_path, screenshots):
    """Chromium answers every question of one episode by keyboard; the page shows the agent's episode and context."""
    suite = tiny_ipref.held_out("rollouts")[0]
    person = BrowserAnnotator(str(tmp_path / "online"))
    url = person.start()
    played, out = agent(max_context=2), {}
    loop = threading.Thread(target=lambda: out.update(online_mdp.online_episodes(
        played, tiny_ipref.family, suite, person, episodes=1, seed=0)))
    loop.start()
    page = browser.new_page(viewport={"width": 1000, "height": 700})
    page.goto(url)
    b = len(suite.task_index)
    try:
        for k in range(2 * b):
            page.wait_for_selector(f"body[data-pair='asked-{k:05d}']", state="attached", timeout=20_000)
            if k == b + 1:  # a question of the second query step: the path and the context are drawn
                assert page.inner_text(".context").startswith("its context (1 answered)")
                page.wait_for_timeout(100)
                page.screenshot(path=screenshots / "label_online_darkroom.png")
            page.keyboard.press("1" if k % 3 else "2")
        loop.join(30)
        assert out["context_length"].tolist() == [2, 2]
        assert played.context.preferred[:, 0].tolist() == [float(k % 3 != 0) for k in range(b)]
        page.wait_for_selector("body[data-pair='done']", state="attached")
        assert "Waiting for the agent" in page.inner_text("#question")
    finally:
        person.stop()


def test_evaluate_online_takes_a_person_in_the_browser(tiny_kwargs, tmp_path, capsys):
    """``icprl evaluate online --browser-session``: the command's agent asks the page; the person answers it."""
    torch.manual_seed(0)
    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=8,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    ckpt = str(save_untrained(module, tmp_path / "icpo.ckpt"))
    setting = {k: v for k, v in tiny_kwargs.items() if k in ("trajectories_per_task", "val_trajectories_per_task",
                                                             "eval_contexts_per_task", "calibration_episodes")}
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.darkroom.DarkRoomFamily",
                                 "init_args": {"horizon": 8}},  # 8-step contexts: few questions
                      "setting": {"class_path": "icprl_lightning.data.settings.StepPreferences",
                                  "init_args": {**setting, "reference_episodes": 4}},
                      "root_dir": str(tmp_path / "data"), "pairs": True}}}))
    session, stop = tmp_path / "online", threading.Event()

    def person() -> None:
        while not (session / "page.url").exists() and not stop.is_set():
            time.sleep(0.01)
        if not stop.is_set():
            bradley_terry_person((session / "page.url").read_text().strip(), stop, np.random.default_rng(1))

    answering = threading.Thread(target=person)
    answering.start()
    try:
        main(["evaluate", "online", "--config", str(config), "--ckpt", ckpt, "--episodes", "2", "--seeds", "0",
              "--browser-session", str(session)])
    finally:
        stop.set()
        answering.join()
    out = json.loads(capsys.readouterr().out)
    assert out["annotator"]["class_path"] == "icprl_lightning.labelling.online.BrowserAnnotator"
    assert out["online"]["action_uniform"]["queries_before_episode"] == [0, 4, 8]
    tasks = out["tasks"] * out["episodes_per_task"]
    assert len((session / "answers.jsonl").read_text().splitlines()) == 8 * tasks
    assert (session / "page.url").stat().st_mode & 0o777 == 0o600


def test_a_person_labels_a_generated_dataset_in_the_browser(tmp_path):
    """As a setting's annotator: T-PRL pairs labelled in the page as the generator draws them."""
    pairs = DarkRoomTrajectories().build(6, 0)
    states = np.concatenate([pairs["states_a"], pairs["states_b"]])
    actions = np.concatenate([pairs["actions_a"], pairs["actions_b"]])
    rewards = np.zeros(actions.shape, dtype=np.float32)
    rewards[:, -1] = np.concatenate([pairs["utility_first"], pairs["utility_second"]])  # the returns
    person = BrowserAnnotator(str(tmp_path / "generation"))
    stop = threading.Event()
    answering = threading.Thread(target=bradley_terry_person, args=(person.start(), stop, np.random.default_rng(0)))
    answering.start()
    try:
        arrays, _, stats = label_trajectory_pairs(states, actions, rewards, 6, person, np.random.default_rng(0),
                                                  tasks=pairs["goal"].astype(int))
    finally:
        stop.set()
        answering.join()
        person.stop()
    log = [json.loads(x) for x in (tmp_path / "generation" / "answers.jsonl").read_text().splitlines()]
    assert arrays["preferred"].tolist() == [int(x["label"] == "first") for x in log]
    asked = [json.loads(x) for x in (tmp_path / "generation" / "asked.jsonl").read_text().splitlines()]
    assert [q["first"] for q in asked] == pairs["states_a"].astype(int).tolist()
