"""Annotators (icprl_lightning/annotators/): each one's labels, the label codes and their resolution, the
settings that take one, the manifest's record of it, and its YAML form through the CLI parser."""

from __future__ import annotations

import json
import math
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest
import yaml
from factories import darkroom_data
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from icprl_lightning.annotators import (
    EQUAL,
    FIRST,
    SECOND,
    SKIP,
    AnnotatorError,
    BradleyTerryAnnotator,
    CallableAnnotator,
    HTTPAnnotator,
    ScriptedTeacher,
    StepQueries,
    TrajectoryQueries,
)
from icprl_lightning.annotators.labels import check_labels, count_labels, resolve_labels
from icprl_lightning.commands import run_cli
from icprl_lightning.data.settings import RewardTrajectories, StepPreferences, TrajectoryPairs
from icprl_lightning.preferences import AgreementTally, expected_agreement, label_agreement, sample_preferences
from icprl_lightning.validation import HyperparameterError

REPO = Path(__file__).resolve().parents[2]
TINY = dict(trajectories_per_task=4, val_trajectories_per_task=2, eval_contexts_per_task=1, calibration_episodes=3,
            reference_episodes=3, n_train_tasks=10, n_test_tasks=5, progress=False)


def step_queries(n: int, seed: int = 0, ties: bool = False) -> StepQueries:
    rng = np.random.default_rng(seed)
    u = rng.integers(-3, 1, n).astype(np.float64) if ties else rng.normal(size=n)
    alt = rng.integers(-3, 1, n).astype(np.float64) if ties else rng.normal(size=n)
    return StepQueries(rng.integers(0, 10, (n, 2)).astype(np.float32), rng.integers(0, 5, n), rng.integers(0, 5, n),
                       u, alt, rng.integers(0, 10, (n, 2)))


def trajectory_queries(rewards_a: np.ndarray, rewards_b: np.ndarray, tasks: np.ndarray | None = None
                       ) -> TrajectoryQueries:
    n, horizon = rewards_a.shape
    path = np.stack(np.meshgrid(np.arange(horizon), np.zeros(1), indexing="ij"), -1).reshape(horizon, 2)
    states = np.broadcast_to(path.astype(np.float32), (n, horizon, 2))
    actions = np.full((n, horizon), 3)
    return TrajectoryQueries(states, actions, rewards_a, states[:, ::-1], actions, rewards_b, tasks)


# ---- label codes ---------------------------------------------------------------------------------------
def test_resolution_keeps_decided_labels_and_leaves_the_stream_alone_when_all_decided():
    rng, twin = np.random.default_rng(3), np.random.default_rng(3)
    decided = np.array([1, 0, 1], dtype=np.uint8)
    assert resolve_labels(decided, rng).tolist() == [1, 0, 1]
    assert rng.random() == twin.random()  # nothing drawn


def test_resolution_turns_skip_and_equal_into_fair_coins_and_counts_them():
    answers = np.array([FIRST, SECOND, EQUAL, SKIP] * 2000, dtype=np.uint8)
    out = resolve_labels(answers, np.random.default_rng(0))
    assert set(out.tolist()) <= {0, 1} and out.dtype == np.uint8
    assert (out[answers <= FIRST] == answers[answers <= FIRST]).all()
    coins = out[answers > FIRST]
    assert abs(coins.mean() - 0.5) < 4 * math.sqrt(0.25 / len(coins))
    assert count_labels(answers) == {"skip_count": 2000, "equal_count": 2000}


# ---- Bradley–Terry --------------------------------------------------------------------------------------
def test_bradley_terry_draws_what_sample_preferences_draws():
    q = step_queries(500)
    got = BradleyTerryAnnotator(0.5).label_steps(q, np.random.default_rng(7))
    assert np.array_equal(got, sample_preferences(q.utility, q.alt_utility, 0.5, np.random.default_rng(7)))
    rewards = np.random.default_rng(1).random((2, 50, 8)).astype(np.float32)
    tq = trajectory_queries(rewards[0], rewards[1])
    got = BradleyTerryAnnotator(2.0).label_trajectories(tq, np.random.default_rng(7))
    want = sample_preferences(rewards[0].sum(1), rewards[1].sum(1), 2.0, np.random.default_rng(7))
    assert np.array_equal(got, want)


# ---- ScriptedTeacher -------------------------------------------------------------------------------------
def test_rational_teacher_always_agrees_with_the_latent_ordering():
    q = step_queries(2000)
    y = ScriptedTeacher().label_steps(q, np.random.default_rng(0))
    assert label_agreement(q.utility, q.alt_utility, y) == 1.0
    rewards = np.random.default_rng(2).random((2, 300, 10))
    y = ScriptedTeacher().label_trajectories(trajectory_queries(rewards[0], rewards[1]), np.random.default_rng(0))
    assert label_agreement(rewards[0].sum(1), rewards[1].sum(1), y) == 1.0


def test_mistakes_flip_about_epsilon_of_the_labels():
    n, eps = 4000, 0.3
    q = step_queries(n, seed=5)
    y = ScriptedTeacher(epsilon=eps).label_steps(q, np.random.default_rng(1))
    flipped = 1.0 - label_agreement(q.utility, q.alt_utility, y)
    assert abs(flipped - eps) < 4 * math.sqrt(eps * (1 - eps) / n), flipped  # 4σ of Binomial(n, ε) / n


def test_finite_rationality_is_bradley_terry_at_temperature_one_over_beta():
    n, beta = 20000, 2.0
    q = StepQueries(np.zeros((n, 2), np.float32), np.zeros(n, int), np.zeros(n, int), np.full(n, 0.5), np.zeros(n))
    y = ScriptedTeacher(beta=beta).label_steps(q, np.random.default_rng(0))
    p = 1 / (1 + math.exp(-beta * 0.5))
    assert abs(y.mean() - p) < 4 * math.sqrt(p * (1 - p) / n)


def test_myopia_weighs_the_last_steps_most():
    # ξ_a earns 2 at its first two steps, ξ_b 1 at its last: ξ_a has the higher return, but with
    # γ = 0.5 over H = 4 the myopic returns are 0.5³ + 0.5² = 0.375 and 1, so ξ_b wins.
    rewards_a, rewards_b = np.array([[1.0, 1.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 0.0, 1.0]])
    q = trajectory_queries(rewards_a, rewards_b)
    assert ScriptedTeacher().label_trajectories(q, np.random.default_rng(0)).tolist() == [FIRST]
    myopic = ScriptedTeacher(gamma=0.5)
    assert myopic.myopic_return(rewards_a).tolist() == [0.375]
    assert myopic.label_trajectories(q, np.random.default_rng(0)).tolist() == [SECOND]
    # at γ = 0.8 the weights are 0.512 + 0.64 = 1.152 > 1: ξ_a again
    assert ScriptedTeacher(gamma=0.8).label_trajectories(q, np.random.default_rng(0)).tolist() == [FIRST]


def test_skip_and_equal_thresholds():
    u = np.array([-3.0, -2.5, 0.0, 0.0, -0.2])
    alt = np.array([-2.0, -2.6, -1.0, 0.05, -5.0])
    q = StepQueries(np.zeros((5, 2), np.float32), np.zeros(5, int), np.zeros(5, int), u, alt)
    y = ScriptedTeacher(skip_threshold=-1.5, equal_threshold=0.1).label_steps(q, np.random.default_rng(0))
    # both below −1.5: skip (even when also equal); |d| < 0.1: equal; else the rational label
    assert y.tolist() == [SKIP, SKIP, FIRST, EQUAL, FIRST]
    assert count_labels(y) == {"skip_count": 2, "equal_count": 1}


@pytest.mark.parametrize(("kwargs", "key"), [
    ({"beta": 0}, "beta"), ({"beta": -1.0}, "beta"), ({"gamma": 0.0}, "gamma"), ({"gamma": 1.5}, "gamma"),
    ({"epsilon": 1.2}, "epsilon"), ({"equal_threshold": -1}, "equal_threshold"),
    ({"skip_threshold": math.inf}, "skip_threshold")])
def test_teacher_knobs_are_range_checked(kwargs, key):
    with pytest.raises(HyperparameterError, match=f"ScriptedTeacher: {key}"):
        ScriptedTeacher(**kwargs)


# ---- CallableAnnotator -------------------------------------------------------------------------------------
def closer_first(queries, rng):
    """A user's label function: the first action wins when its utility is higher (ties: second)."""
    return (queries.utility > queries.alt_utility).astype(np.int8)


def test_callable_labels_and_records_its_function():
    q = step_queries(50)
    annotator = CallableAnnotator(closer_first)
    assert np.array_equal(annotator.label_steps(q, np.random.default_rng(0)), q.utility > q.alt_utility)
    assert annotator.config() == {"class_path": "icprl_lightning.annotators.CallableAnnotator",
                                  "init_args": {"fn": f"{__name__}.closer_first"}}


@pytest.mark.parametrize(("answer", "message"), [
    ([1, 0, 1], "numpy array of shape \\(3,\\), got list"),
    (np.ones(4, np.uint8), "shape \\(3,\\) \\(one per pair\\), got \\(4,\\)"),
    (np.ones((3, 1), np.uint8), "got \\(3, 1\\)"),
    (np.ones(3), "integer array .* got dtype float64"),
    (np.ones(3, bool), "got dtype bool"),
    (np.array([1, 7, -1]), "got \\[-1, 7\\] at pair\\(s\\) \\[1, 2\\]"),
])
def test_callable_output_is_checked_with_an_error_naming_what_is_wrong(answer, message):
    annotator = CallableAnnotator(lambda queries, rng: answer)
    with pytest.raises(AnnotatorError, match=message):
        annotator.label_steps(step_queries(3), np.random.default_rng(0))


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(st.sampled_from([np.int8, np.uint8, np.int64, np.float32, np.bool_]),
                  hnp.array_shapes(min_dims=1, max_dims=2, max_side=5), elements={"min_value": 0, "max_value": 4}))
def test_callable_output_fuzz(answer):
    """Accepted exactly when it is an integer array of one known code per pair, and then unchanged."""
    n = 4
    ok = answer.shape == (n,) and answer.dtype != np.bool_ and np.issubdtype(answer.dtype, np.integer) and \
        bool(np.isin(answer, [0, 1, 2, 3]).all())
    annotator = CallableAnnotator(lambda queries, rng: answer)
    if ok:
        got = annotator.label_trajectories(trajectory_queries(np.zeros((n, 3)), np.zeros((n, 3))), None)
        assert got.dtype == np.uint8 and got.tolist() == answer.tolist()
    else:
        with pytest.raises(AnnotatorError, match="CallableAnnotator"):
            check_labels(answer, n, "CallableAnnotator(fuzz)")


def test_callable_needs_a_callable():
    with pytest.raises(HyperparameterError, match="fn must be callable"):
        CallableAnnotator(3)


# ---- HTTPAnnotator against a local server -------------------------------------------------------------------
class Endpoint(BaseHTTPRequestHandler):
    """/plain answers "2", /json {"answer": " Equal "}, /skip "SKIP", /bad a sentence, /slow too late,
    /flaky a 500 then "1", /missing 404. Prompts are kept in ``server.prompts``."""

    def do_POST(self):  # noqa: N802 (http.server's name)
        prompt = json.loads(self.rfile.read(int(self.headers["Content-Length"])))["prompt"]
        self.server.prompts.append((self.path, prompt))
        if self.path == "/slow":
            time.sleep(1.0)
        if self.path == "/flaky" and sum(p == "/flaky" for p, _ in self.server.prompts) == 1:
            self.send_error(500)
            return
        if self.path == "/missing":
            self.send_error(404)
            return
        body = {"/plain": "2", "/json": json.dumps({"answer": " Equal "}), "/skip": "SKIP",
                "/bad": "I think the first one, probably", "/slow": "1", "/flaky": "1"}[self.path]
        self.send_response(200)
        self.end_headers()
        self.wfile.write(body.encode())

    def log_message(self, *args):
        pass


@pytest.fixture
def endpoint():
    server = ThreadingHTTPServer(("127.0.0.1", 0), Endpoint)
    server.daemon_threads = True
    server.prompts = []
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server, f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()
    thread.join(5)


def darkroom_pair() -> TrajectoryQueries:
    return trajectory_queries(np.zeros((1, 4)), np.ones((1, 4)), tasks=np.array([[3, 0]]))


@pytest.mark.parametrize(("path", "code"), [("/plain", SECOND), ("/json", EQUAL), ("/skip", SKIP)])
def test_http_answers_are_parsed(endpoint, path, code):
    server, url = endpoint
    y = HTTPAnnotator(url + path, timeout=5).label_trajectories(darkroom_pair(), np.random.default_rng(0))
    assert y.tolist() == [code]
    _, prompt = server.prompts[0]
    assert "goal cell (3, 0)" in prompt
    assert "Trajectory 1 visited: (0, 0) (1, 0) (2, 0) (3, 0)" in prompt
    assert "Trajectory 2 visited: (3, 0) (2, 0) (1, 0) (0, 0)" in prompt


def test_http_step_prompt_names_the_cell_goal_and_actions(endpoint):
    server, url = endpoint
    q = StepQueries(np.array([[2.0, 5.0]], np.float32), np.array([3]), np.array([4]), np.zeros(1), np.zeros(1),
                    np.array([[7, 5]]))
    assert HTTPAnnotator(url + "/plain").label_steps(q, np.random.default_rng(0)).tolist() == [SECOND]
    prompt = server.prompts[0][1]
    assert "cell (2, 5)" in prompt and "(7, 5)" in prompt and "Action 1: right" in prompt and "Action 2: stay" in prompt


def test_http_malformed_reply_is_a_clear_error(endpoint):
    server, url = endpoint
    with pytest.raises(AnnotatorError, match=f"{url}/bad: the answer must be 1, 2, skip or equal .* got 'I think"):
        HTTPAnnotator(url + "/bad", retries=3, backoff=0).label_trajectories(darkroom_pair(), None)
    assert len(server.prompts) == 1  # asking again would not help


def test_http_timeout_is_retried_then_an_error(endpoint):
    server, url = endpoint
    start = time.monotonic()
    with pytest.raises(AnnotatorError, match=f"{url}/slow: no complete reply within the 0.2 s deadline .*2 tries"):
        HTTPAnnotator(url + "/slow", timeout=0.2, retries=1, backoff=0.05).label_trajectories(darkroom_pair(), None)
    assert len(server.prompts) == 2 and time.monotonic() - start < 3


def test_http_server_error_is_retried_client_error_is_not(endpoint):
    server, url = endpoint
    assert HTTPAnnotator(url + "/flaky", retries=2, backoff=0.01).label_trajectories(darkroom_pair(), None) == [FIRST]
    with pytest.raises(AnnotatorError, match="answered HTTP 404"):
        HTTPAnnotator(url + "/missing", retries=2, backoff=0).label_trajectories(darkroom_pair(), None)


def test_http_template_fields_are_checked():
    with pytest.raises(HyperparameterError, match="unknown field\\(s\\) \\['reward'\\]"):
        HTTPAnnotator("http://127.0.0.1:1", template="{trajectory_1} {reward}")
    for url in ("ftp://x", "http://", "http://host:port/", "http://host:0/", 3):
        with pytest.raises(HyperparameterError, match="url must be http:// or https:// with a host"):
            HTTPAnnotator(url)
    with pytest.raises(HyperparameterError, match="follow_redirects must be true or false, got 1"):
        HTTPAnnotator("http://127.0.0.1:1", follow_redirects=1)
    with pytest.raises(HyperparameterError, match="max_reply_bytes must be >= 1"):
        HTTPAnnotator("http://127.0.0.1:1", max_reply_bytes=0)
    args = HTTPAnnotator("http://[::1]:8/x", follow_redirects=True, max_reply_bytes=10).init_args()
    assert (args["follow_redirects"], args["max_reply_bytes"]) == (True, 10)


# ---- settings take an annotator --------------------------------------------------------------------------------
def test_bt_temperature_and_annotator_together_is_an_error_naming_both():
    for cls in (StepPreferences, TrajectoryPairs):
        with pytest.raises(HyperparameterError, match="bt_temperature \\(0.5\\) and annotator \\(ScriptedTeacher\\)"):
            cls(bt_temperature=0.5, annotator=ScriptedTeacher())
    with pytest.raises(HyperparameterError, match="RewardTrajectories: annotator has no effect"):
        RewardTrajectories(annotator=ScriptedTeacher())


def test_default_annotator_keeps_the_config_and_bt_temperature():
    for cls in (StepPreferences, TrajectoryPairs):
        assert cls(bt_temperature=0.25).config() == cls(annotator=BradleyTerryAnnotator(0.25)).config()
        assert cls(bt_temperature=0.25).config()["bt_temperature"] == 0.25
        assert "annotator" not in cls().config() and cls().bt_temperature == 1.0
        other = cls(annotator=ScriptedTeacher(epsilon=0.1))
        assert other.bt_temperature is None and "bt_temperature" not in other.config()
        assert other.config()["annotator"]["init_args"]["epsilon"] == 0.1


@pytest.mark.parametrize("kind", ["step_preference", "trajectory_preference"])
def test_manifest_records_the_annotator_and_its_counts(kind, tmp_path):
    # DarkRoom's A* is ≤ 0 (a step off the optimal path costs 1); its returns count steps on the goal (≈ 40)
    step = kind == "step_preference"
    teacher = ScriptedTeacher(epsilon=0.2, equal_threshold=0.5 if step else 3.0, skip_threshold=-0.5 if step else 20.0)
    dm = darkroom_data(context_kind=kind, root_dir=str(tmp_path), annotator=teacher, **TINY)
    dm.prepare_data()
    data = dm.load()
    info = data.manifest["info"]
    assert info["annotator"] == json.loads(json.dumps(teacher.config()))
    assert data.manifest["config"]["annotator"]["class_path"] == "icprl_lightning.annotators.ScriptedTeacher"
    stats = info["train_statistics"]
    assert stats["skip_count"] > 0 and stats["equal_count"] > 0, stats
    assert 0.5 < stats["label_agreement"] < 1.0  # mistakes and coin-resolved answers
    for split in ("train", "val", "eval_low"):
        assert set(np.unique(np.asarray(data[split]["preferred"])).tolist()) <= {0, 1}
    default = darkroom_data(context_kind=kind, root_dir=str(tmp_path), **TINY)
    assert default.path != dm.path  # another annotator, another dataset


def test_a_scripted_teacher_config_instantiates_through_the_cli(tmp_path, monkeypatch):
    overlay = tmp_path / "teacher.yaml"
    overlay.write_text(yaml.safe_dump({"data": {"init_args": {"setting": {"init_args": {"annotator": {
        "class_path": "icprl_lightning.annotators.ScriptedTeacher",
        "init_args": {"beta": 10.0, "gamma": 0.9, "epsilon": 0.1, "equal_threshold": 0.05}}}}}}}))
    monkeypatch.chdir(tmp_path)
    cli = run_cli(["--config", str(REPO / "configs/icpo_darkroom.yaml"), "--config", str(overlay),
                   "--trainer.default_root_dir", str(tmp_path)], run=False)
    annotator = cli.datamodule.setting.annotator
    assert isinstance(annotator, ScriptedTeacher)
    assert (annotator.beta, annotator.gamma, annotator.epsilon, annotator.equal_threshold) == (10.0, 0.9, 0.1, 0.05)


def test_a_callable_annotator_is_named_by_its_import_path_in_yaml(tmp_path, monkeypatch):
    overlay = tmp_path / "fn.yaml"
    overlay.write_text(yaml.safe_dump({"data": {"init_args": {"setting": {"init_args": {"annotator": {
        "class_path": "icprl_lightning.annotators.CallableAnnotator",
        "init_args": {"fn": "test_annotators.closer_first"}}}}}}}))
    monkeypatch.chdir(tmp_path)
    cli = run_cli(["--config", str(REPO / "configs/icpo_darkroom.yaml"), "--config", str(overlay),
                   "--trainer.default_root_dir", str(tmp_path)], run=False)
    assert cli.datamodule.setting.annotator.fn.__name__ == "closer_first"


def test_a_bandit_teacher_relabels_pretraining_duels_only(tmp_path):
    """BanditDuels(annotator=...): train/val labels from the teacher, held-out contexts unchanged, recorded."""
    from factories import bandit_data

    from icprl_lightning.annotators import ScriptedTeacher

    tiny = dict(n_train_problems=40, contexts_per_problem=2, n_val_problems=8, n_eval_problems=10, horizon=20,
                progress=False)
    clean = bandit_data(data_dir=str(tmp_path / "clean"), **tiny)
    noisy = bandit_data(data_dir=str(tmp_path / "noisy"), annotator=ScriptedTeacher(beta=math.inf, epsilon=0.3),
                        **tiny)
    for dm in (clean, noisy):
        dm.prepare_data()
    a, b = clean.load(), noisy.load()
    assert "annotator" not in clean.setting.config()  # the default dataset's config (and hash) is unchanged
    for split in ("eval_uniform", "eval_dirichlet", "eval_dts"):
        assert np.array_equal(a[split]["preferred"], b[split]["preferred"])
    assert np.array_equal(a["train"]["actions"], b["train"]["actions"])  # same duels, new labels
    info = b.manifest["info"]
    assert info["annotator"]["class_path"].endswith("ScriptedTeacher")
    assert info["annotator"]["init_args"]["epsilon"] == 0.3
    # a deterministic teacher that errs 30% of the time agrees with the reward order on ≈ 70% of duels
    assert 0.6 < info["label_agreement"]["train"] < 0.8
    assert info["label_agreement"]["eval_uniform"] == a.manifest["info"]["label_agreement"]["eval_uniform"]


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 60), st.integers(1, 5), st.integers(0, 2**32 - 1))
def test_agreement_tally_equals_the_whole_array_statistics(n, blocks, seed):
    """The generator's step-by-step tally (AgreementTally) gives what the whole-array functions give on the
    same pairs: ties (integer utilities), all-tie inputs and any split into blocks included."""
    rng = np.random.default_rng(seed)
    first, second = rng.integers(-2, 3, size=(2, n)).astype(np.float64)
    if rng.random() < 0.5:  # continuous utilities too
        first, second = first + rng.normal(size=n), second + rng.normal(size=n) * (rng.random(n) < 0.5)
    y = rng.integers(0, 2, size=n).astype(np.uint8)
    tally = AgreementTally()
    for part in np.array_split(np.arange(n), blocks):
        tally.add(first[part], second[part], y[part])
    got = tally.summary()
    gap = np.abs(first - second)
    want = {"label_agreement": label_agreement(first, second, y), "tie_fraction": float(np.mean(gap == 0)),
            "median_utility_gap": float(np.median(gap[gap != 0])) if np.any(gap != 0) else 0.0,
            "expected_agreement_by_bt_temperature": expected_agreement(first, second)}
    assert got.keys() == want.keys()
    for key in ("label_agreement", "tie_fraction", "median_utility_gap"):
        assert got[key] == pytest.approx(want[key], rel=1e-12, nan_ok=True), key
    for t, value in want["expected_agreement_by_bt_temperature"].items():
        assert got["expected_agreement_by_bt_temperature"][t] == pytest.approx(value, rel=1e-12, nan_ok=True), t
