"""A user's own evaluation (evaluation/base.py, registry.EVALUATIONS) is a peer of the built-in tables: icprl
evaluate runs it, an experiment file names it, and the renderer draws its table from its JSON alone.
docs/extending_evaluations.md runs one end to end from outside the package; here the pieces, each with the case
that would break it.
"""

from __future__ import annotations

import json

import pytest

from icprl_lightning import register_evaluation
from icprl_lightning.evaluation.base import KIND, HeldOutEvaluation, evaluation_of
from icprl_lightning.registry import EVALUATIONS
from icprl_lightning.reproduce.render import folder_tables, is_evaluation


class CountContexts(HeldOutEvaluation):
    """A seventh kind of evaluation, defined in a test: the number of held-out contexts per quality."""

    name = "count_contexts"

    def run(self, runs, seeds):
        return {"results": {run.name: {s.quality: s.context.batch_size for s in run.data.held_out("rollouts")}
                            for run in runs}}

    @staticmethod
    def markdown(payload):
        return "".join(f"{name}: {row}\n" for name, row in payload["results"].items())


@pytest.fixture
def registered():
    register_evaluation(CountContexts)
    yield CountContexts
    EVALUATIONS.forget("count_contexts")


def test_the_renderer_draws_a_registered_evaluations_table_from_its_json(registered, tmp_path):
    payload = {KIND: "count_contexts", "title": "t", "results": {"ICPO": {"low": 40}},
               "reference_rows_from": "ICPO"}  # even beside the built-in tables' own key, its kind decides
    (tmp_path / "table_counts.json").write_text(json.dumps(payload))
    assert not is_evaluation(payload) and evaluation_of(payload) is CountContexts
    assert folder_tables(tmp_path) == {tmp_path / "table_counts.md": "ICPO: {'low': 40}\n"}


def test_a_json_naming_an_evaluation_that_is_not_registered_is_one_error(tmp_path):
    (tmp_path / "x.json").write_text(json.dumps({KIND: "os.system", "results": {}}))
    with pytest.raises(ValueError, match="'os.system' is not a registered evaluation"):
        folder_tables(tmp_path)


def test_icprl_evaluate_refuses_an_unregistered_evaluation_before_any_data(tmp_path, capsys):
    from icprl_lightning.commands import main

    config = tmp_path / "c.yaml"
    config.write_text("model: {}\n")
    with pytest.raises(SystemExit) as exit_:
        main(["evaluate", "--evaluation", "nope", "--run", f"A={config}:{tmp_path / 'x.ckpt'}",
              "--out", str(tmp_path / "o")])
    assert exit_.value.code == 2 and not (tmp_path / "o.json").exists()


def test_an_experiment_file_turns_evaluation_and_options_into_the_commands_flags(registered, tmp_path):
    from icprl_lightning.reproduce.experiments import TableError, load_table

    path = tmp_path / "t.yaml"
    text = ("title: t\nruns: [{name: A, configs: [configs/smoke.yaml]}]\n"
            "evaluations: [{suffix: _c, evaluation: %s, options: {step: 3, names: [a, b]}}]\n")
    path.write_text(text % "count_contexts")
    evaluation = load_table(str(path)).evaluations[0]
    assert evaluation.flags == ("--evaluation", "count_contexts", "--option", "step=3", "--option", "names=[a, b]")
    path.write_text(text % "unknown_kind")
    with pytest.raises(TableError, match="evaluations.*evaluation.*'unknown_kind' is not a registered evaluation"):
        load_table(str(path))


def test_register_evaluation_takes_only_an_evaluation_class():
    with pytest.raises(TypeError, match="register_evaluation"):
        register_evaluation(dict)


BUILT_IN = {"rollouts": "darkroom_ipref/darkroom_ipref.json", "duels": "bandit/bandit.json",
            "online": "online_darkroom_uniform/online_darkroom_uniform.json",
            "online_duels": "online_bandit/online_bandit_active.json", "ad": "ad_darkroom/ad_darkroom.json",
            "pair_accuracy": None}


def test_the_six_built_in_kinds_are_registered_evaluations_each_in_its_own_file():
    kinds = {name: EVALUATIONS.get(name) for name in BUILT_IN}
    assert all(issubclass(kind, HeldOutEvaluation) and kind.name == name for name, kind in kinds.items())
    assert len({kind.__module__ for kind in kinds.values()}) == len(BUILT_IN)


@pytest.mark.parametrize("name", [n for n, path in BUILT_IN.items() if path])
def test_each_committed_results_json_is_read_by_its_own_kind_alone(name):
    from icprl_lightning.untrusted import read_json

    payload = read_json(f"docs/results/{BUILT_IN[name]}", "results")
    assert evaluation_of(payload) is EVALUATIONS.get(name)
    assert [n for n in BUILT_IN if EVALUATIONS.get(n).recognizes(payload)] == [name]
