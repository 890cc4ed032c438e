"""The labelling server refuses hostile requests with a 4xx and leaves the answer log's bytes as they were."""

from __future__ import annotations

import pytest
from starlette.testclient import TestClient

from icprl_lightning.labelling.server import MAX_BODY, make_app
from icprl_lightning.labelling.session import open_session

TOKEN = "t0ken-for-tests"


@pytest.fixture
def served(tmp_path):
    session = open_session(tmp_path / "session", "darkroom_steps", 6, 0)
    (tmp_path / "secret.txt").write_text("outside the session")
    client = TestClient(make_app(session, TOKEN), base_url="http://127.0.0.1")
    answer(client, "alice", "darkroom_steps-00000", "first", "nonce0001")  # one answer on the log already
    return client, session


def answer(client, who, pair, label, nonce, **extra):
    body = {"annotator": who, "pair": pair, "label": label, "nonce": nonce, "response_ms": 250, **extra}
    return client.post(f"/api/answer?token={TOKEN}", json=body)


def log_bytes(session) -> bytes:
    return session.log.path.read_bytes()


def refused(client, session, request, status):
    before, state = log_bytes(session), {k: list(v) for k, v in session.log.answers.items()}
    response = request(client)
    assert response.status_code == status, response.text
    assert log_bytes(session) == before
    assert {k: list(v) for k, v in session.log.answers.items()} == state


def test_an_honest_answer_is_logged(served):
    client, session = served
    response = answer(client, "alice", "darkroom_steps-00001", "equal", "nonce0002")
    assert response.status_code == 200
    assert response.json()["pair"] == "darkroom_steps-00002"
    assert log_bytes(session).count(b"\n") == 2


@pytest.mark.parametrize("query", ["", "?token=", "?token=wrong", f"?token={TOKEN}x", f"?tok={TOKEN}"])
def test_a_missing_or_wrong_token_is_forbidden(served, query):
    client, session = served
    refused(client, session, lambda c: c.get(f"/{query}"), 403)
    refused(client, session, lambda c: c.get(f"/api/pair{query}{'&' if query else '?'}annotator=alice"), 403)
    refused(client, session, lambda c: c.post(f"/api/answer{query}", json={
        "annotator": "alice", "pair": "darkroom_steps-00001", "label": "first", "nonce": "nonce0003",
        "response_ms": 1}), 403)


@pytest.mark.parametrize("pair, status", [("darkroom_steps-99999", 409), ("darkroom_steps-00000", 409),
                                          ("darkroom_steps-00002", 409), ("bandit_duels-00001", 409),
                                          ("../../secret.txt", 400), ("", 400)])
def test_a_forged_or_out_of_turn_pair_is_refused(served, pair, status):
    client, session = served
    refused(client, session, lambda c: answer(c, "alice", pair, "first", "nonce0004"), status)


@pytest.mark.parametrize("who", ["../alice", "al ice", "", "a" * 41, "alice/../../x"])
def test_a_bad_annotator_name_is_refused(served, who):
    client, session = served
    refused(client, session, lambda c: answer(c, who, "darkroom_steps-00000", "first", "nonce0005"), 400)
    refused(client, session, lambda c: c.get(f"/api/pair?token={TOKEN}&annotator={who}"), 400)


@pytest.mark.parametrize("label", ["best", "FIRST", "1", "undo", ""])
def test_a_label_outside_the_allowed_set_is_refused(served, label):
    client, session = served
    refused(client, session, lambda c: answer(c, "alice", "darkroom_steps-00001", label, "nonce0006"), 400)


def test_a_replayed_answer_is_refused(served):
    client, session = served
    # the same request again: its nonce was seen (and its pair is no longer the one shown)
    refused(client, session, lambda c: answer(c, "alice", "darkroom_steps-00000", "first", "nonce0001"), 409)
    # a replayed nonce on the right pair, and on an undo
    refused(client, session, lambda c: answer(c, "alice", "darkroom_steps-00001", "first", "nonce0001"), 409)
    refused(client, session, lambda c: c.post(f"/api/undo?token={TOKEN}",
                                              json={"annotator": "alice", "nonce": "nonce0001"}), 409)
    # an undo with nothing to take back
    refused(client, session, lambda c: c.post(f"/api/undo?token={TOKEN}",
                                              json={"annotator": "bob", "nonce": "nonce0007"}), 409)


@pytest.mark.parametrize("body", [b"{not json", b"\xff\xfe", b"[1, 2]", b'"first"', b"",
                                  b'{"annotator": "alice", "pair": "darkroom_steps-00001", "label": "first", '
                                  b'"nonce": "nonce0008", "response_ms": "250"}',
                                  b'{"annotator": "alice", "pair": "darkroom_steps-00001", "label": "first", '
                                  b'"nonce": "nonce0008", "response_ms": 250, "goal": [1, 2]}',
                                  b'{"annotator": "alice", "pair": "darkroom_steps-00001", "label": "first", '
                                  b'"nonce": "nonce0008", "response_ms": -1}',
                                  b'{"annotator": "alice", "pair": "darkroom_steps-00001", "label": "first", '
                                  b'"nonce": "short", "response_ms": 250}'])
def test_a_malformed_body_is_refused(served, body):
    client, session = served
    refused(client, session, lambda c: c.post(f"/api/answer?token={TOKEN}", content=body,
                                              headers={"Content-Type": "application/json"}), 400)


def test_an_oversized_body_is_refused(served):
    client, session = served
    big = b'{"annotator": "alice", "pad": "' + b"x" * MAX_BODY + b'"}'
    refused(client, session, lambda c: c.post(f"/api/answer?token={TOKEN}", content=big), 413)

    def chunked(c):  # no Content-Length: the stream is cut at MAX_BODY
        return c.post(f"/api/answer?token={TOKEN}", content=iter([big[:1000]] * 10))
    refused(client, session, chunked, 413)


@pytest.mark.parametrize("path", ["/../secret.txt", "/..%2f..%2fsecret.txt", "/session.json", "/answers.jsonl",
                                  "/queue.npz", "/assets/app.js", "/assets/..%2f..%2fsession.py",
                                  "/%2e%2e/%2e%2e/etc/passwd", "/api/../../secret.txt"])
def test_no_path_outside_the_routes_is_served(served, path):
    client, session = served
    refused(client, session, lambda c: c.get(f"{path}?token={TOKEN}"), 404)


def test_a_foreign_host_is_refused(served):
    """DNS rebinding: a page on evil.example resolving to 127.0.0.1 sends its own Host."""
    client, session = served
    refused(client, session, lambda c: c.get(f"/?token={TOKEN}", headers={"Host": "evil.example"}), 400)
    body = {"annotator": "alice", "pair": "darkroom_steps-00001", "label": "first", "nonce": "nonce0009",
            "response_ms": 1}
    refused(client, session, lambda c: c.post(f"/api/answer?token={TOKEN}", headers={"Host": "evil.example:8765"},
                                              json=body), 400)


def test_wrong_methods_are_refused(served):
    client, session = served
    refused(client, session, lambda c: c.get(f"/api/answer?token={TOKEN}"), 405)
    refused(client, session, lambda c: c.put(f"/api/answer?token={TOKEN}", json={}), 405)


def test_command_mistakes_are_one_line(tmp_path, capsys):
    from icprl_lightning.commands import main

    for argv, message in ((["--session", str(tmp_path / "new")], "--view must be one of"),
                          (["--session", str(tmp_path / "new"), "--view", "darkroom_steps", "--pairs", "0"],
                           "--pairs must be an integer in [1, 10000]")):
        capsys.readouterr()
        with pytest.raises(SystemExit) as info:
            main(["label", *argv])
        err = capsys.readouterr().err
        assert info.value.code == 2 and err.count("\n") == 1 and err.startswith("icprl label: error: ") and \
            message in err, err
    assert not (tmp_path / "new").exists()
    open_session(tmp_path / "s", "darkroom_steps", 3, 0)
    with pytest.raises(ValueError, match="holds a session with view 'darkroom_steps', not 'bandit_duels'"):
        open_session(tmp_path / "s", "bandit_duels", 3, 0)
