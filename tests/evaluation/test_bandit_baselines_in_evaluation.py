"""The feature-aware dueling-bandit baselines and the Bayes reference inside the bandit evaluation: every row of
``icprl evaluate`` and ``icprl evaluate online`` with weak and strong regret, the strong regret by hand, and the
Bayes reference as the floor of the learners fed the same comparisons."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from factories import save_untrained

from icprl_lightning.commands import main
from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.data.suites import BanditSuite
from icprl_lightning.evaluation import online_bandit
from icprl_lightning.evaluation.duels import (
    BASELINES,
    baseline_curves,
    dts_duels,
    regret_curve,
    regret_curves,
    summarize_regret,
    summarize_regrets,
)
from icprl_lightning.evaluation.online_command import evaluate_online
from icprl_lightning.families.dueling_bandit import LinearDuelingBanditFamily
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.metrics import mean_sem
from icprl_lightning.models.config import TransformerConfig

ARMS, DIM, HORIZON = 5, 3, 60
ROWS = ["ICPO", "dts", "maxinp", "bt_thompson", "bayes", "behavior"]


def _config(tmp_path: Path) -> Path:
    config = tmp_path / "bandit.yaml"
    config.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.dueling_bandit.LinearDuelingBanditFamily",
                                 "init_args": {"n_arms": ARMS, "dim": DIM, "horizon": HORIZON}},
                      "setting": {"class_path": "icprl_lightning.data.settings.BanditDuels",
                                  "init_args": {"n_train_problems": 8, "n_val_problems": 2, "n_eval_problems": 6}},
                      "root_dir": str(tmp_path / "data"), "pairs": True, "progress": False}}}))
    return config


def _checkpoint(tmp_path: Path) -> str:
    torch.manual_seed(0)
    module = ICPOModule(state_dim=0, action_dim=ARMS, discrete=True, max_context=HORIZON,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    return str(save_untrained(module, tmp_path / "icpo.ckpt"))


def test_strong_regret_curve_and_its_summary_by_hand():
    rewards = torch.tensor([[0.0, 1.0, 3.0], [2.0, 2.0, 0.0]], dtype=torch.float64)  # gaps [3, 2, 0], [0, 0, 2]
    duels = (torch.tensor([[0, 2, 2], [2, 0, 1]]), torch.tensor([[1, 0, 2], [2, 1, 2]]))
    curves = regret_curves(rewards, duels)
    # strong = (Δ(a) + Δ(a')) / 2: row 0 (3 + 2) / 2, (0 + 3) / 2, 0; row 1 (2 + 2) / 2, 0, (0 + 2) / 2
    torch.testing.assert_close(curves["strong"], torch.tensor([[2.5, 1.5, 0.0], [2.0, 0.0, 1.0]], dtype=torch.float64))
    torch.testing.assert_close(curves["weak"], torch.tensor([[2.0, 0.0, 0.0], [2.0, 0.0, 0.0]], dtype=torch.float64))
    summary = summarize_regret(curves["strong"], with_tasks=True, regret="strong", sizes=(1, 2, 10))
    assert summary["strong_regret"] == 0.5 and summary["strong_regret_sem"] == pytest.approx(0.5)  # (0, 1)
    assert summary["strong_regret_auc"] == pytest.approx((4.0 / 3.0 + 1.0) / 2)
    assert (summary["strong_regret_h1"], summary["strong_regret_h2"]) == (2.25, 0.75)
    assert "strong_regret_h10" not in summary  # beyond H = 3
    assert summary["per_task"] == {"strong_regret": [0.0, 1.0], "strong_regret_auc": [pytest.approx(4.0 / 3.0), 1.0],
                                   "strong_regret_h1": [2.5, 2.0], "strong_regret_h2": [1.5, 0.0]}
    both = summarize_regrets(curves, with_tasks=True, sizes=(2,))
    assert set(both["per_task"]) == {f"{r}_regret{s}" for r in ("weak", "strong") for s in ("", "_auc", "_h2")}
    assert both["weak_regret_h2"] == 0.0 and both["strong_regret_h2"] == 0.75
    with pytest.raises(ValueError, match="regret must be one of weak, strong"):
        regret_curve(rewards, duels, "average")


def test_icprl_evaluate_reports_every_row_with_weak_and_strong_regret(tmp_path, capsys):
    config, checkpoint = _config(tmp_path), _checkpoint(tmp_path)
    out = tmp_path / "eval"
    main(["evaluate", "--seeds", "0", "--title", "bandit", "--run", f"ICPO={config}:{checkpoint}", "--out", str(out)])
    payload = json.loads(out.with_suffix(".json").read_text())
    assert list(payload["results"]) == ROWS == ["ICPO", *BASELINES]
    assert list(payload["curves"]) == list(payload["strong_curves"]) == ROWS
    metrics = {f"{r}_regret{s}" for r in ("weak", "strong") for s in ("", "_auc", "_h10", "_h50")}
    for name, per_source in payload["results"].items():
        assert list(per_source) == ["uniform", "dirichlet", "dts"]
        for row in per_source.values():
            assert metrics | {f"{m}_sem" for m in metrics} | {"per_task"} == set(row)  # 100 and 200 exceed H = 60
            assert set(row["per_task"]) == metrics and all(len(v) == 1 and len(v[0]) == 6
                                                           for v in row["per_task"].values())
            for key in metrics:  # the per-problem values are what the summary averages
                assert row[key] == pytest.approx(np.mean(row["per_task"][key][0]))
            if name != "bayes":  # one duel scored twice: the average of two gaps is at least the smaller one
                assert row["strong_regret_auc"] >= row["weak_regret_auc"]
    markdown = out.with_suffix(".md").read_text()
    for title in ("weak regret at h = H:", "strong regret at h = H:", "strong regret, mean over h = 1..H:",
                  "weak regret at h = 10:", "strong regret at h = 50:"):
        assert title in markdown
    assert "weak regret at h = 100:" not in markdown
    assert all(f"| {name} |" in markdown for name in ROWS)
    assert out.with_suffix(".png").stat().st_size > 0
    assert "strong regret at h = H:" in capsys.readouterr().out


def _prior_suite(family: LinearDuelingBanditFamily, n: int, seed: int) -> BanditSuite:
    """``n`` problems drawn from the family's prior with uniform-pair contexts, as a held-out suite."""
    rng = np.random.default_rng(seed)
    theta = family.sample_tasks(n, rng)
    ctx = family.uniform_pairs_context(theta, rng)
    first, second = torch.from_numpy(ctx["arms_first"]).long(), torch.from_numpy(ctx["arms_second"]).long()
    context = StepPreferenceContext(torch.zeros(n, family.horizon, 0), first, second,
                                    torch.from_numpy(ctx["preferred"]).float())
    return BanditSuite("uniform", context, torch.from_numpy(family.expected_rewards(theta)), first, second)


def test_the_bayes_reference_is_the_floor_of_the_learners_on_problems_from_the_prior():
    """The Bayes rule minimizes the expected regret over problems drawn from the prior, so no learner fed the same
    comparisons is below it beyond noise; it is a reference, not a learner (it knows the prior)."""
    family = LinearDuelingBanditFamily(n_arms=6, dim=3, horizon=20, seed=0)
    suite = _prior_suite(family, 400, seed=1)
    curves = baseline_curves(suite, family, seed=0)
    curves["dts"] = regret_curves(suite.expected_rewards, dts_duels(suite.context, family.n_arms,
                                                                     np.random.default_rng(2), progress=False))
    for regret in ("weak", "strong"):
        bayes = curves["bayes"][regret].numpy().mean(1)  # each problem's regret averaged over h
        for learner in ("maxinp", "bt_thompson", "dts"):
            gap, gap_sem = mean_sem(curves[learner][regret].numpy().mean(1) - bayes)  # paired over problems
            assert gap > -2 * gap_sem, (regret, learner, gap, gap_sem)
        # not vacuous: DTS ignores the features and pays for it
        gap, gap_sem = mean_sem(curves["dts"][regret].numpy().mean(1) - bayes)
        assert gap > 3 * gap_sem, (regret, gap, gap_sem)
    # two distinct arms are never both optimal: BT Thompson sampling (never self-dueling) pays strong regret
    # every round, while the floor's self-duel of the posterior-best arm does not
    assert (curves["bt_thompson"]["strong"] > 0).all() and (curves["bayes"]["strong"] == 0).any()


def test_online_evaluation_plays_the_feature_aware_baselines_with_both_regrets(tmp_path):
    config, checkpoint = _config(tmp_path), _checkpoint(tmp_path)
    common = {"configs": [config], "checkpoints": [checkpoint], "rounds": 15, "seeds": [0, 1]}
    out = evaluate_online(**common, out=tmp_path / "online")
    for key in ("dts", *online_bandit.ONLINE_BASELINES):
        result = out[key]
        assert set(online_bandit.REGRET_KEYS) <= set(result) and len(result["recommendation_curve"]) == 15
        assert result["cumulative_strong_regret"] >= result["cumulative_weak_regret"] >= 0
    icpo = out["icpo"]["action_uniform"]["mean"]
    assert icpo["cumulative_strong_regret"] >= icpo["cumulative_weak_regret"] >= 0
    assert (tmp_path / "online.png").stat().st_size > 0
    flipped = evaluate_online(**common, labels="flipped")
    for key in ("dts", *online_bandit.ONLINE_BASELINES):  # the baselines keep the true labels
        assert flipped[key] == out[key]


def test_linear_online_is_seeded_and_recommends_after_every_answer():
    family = LinearDuelingBanditFamily(n_arms=6, dim=3, horizon=20, seed=0)
    theta = family.sample_tasks(4, np.random.default_rng(0))
    play = [online_bandit.linear_online(family, theta, 12, "bt_thompson", np.random.SeedSequence(5)) for _ in range(2)]
    assert all(torch.equal(play[0][k], play[1][k]) for k in ("first", "second", "recommended"))
    assert play[0]["recommended"].shape == (4, 12) and (play[0]["first"] != play[0]["second"]).all()
    curves = online_bandit.regrets(torch.from_numpy(family.expected_rewards(theta)), play[0])
    assert set(curves) == {"weak", "strong", "recommendation"} and (curves["strong"] >= curves["weak"]).all()
    with pytest.raises(ValueError, match="online baseline"):
        online_bandit.linear_online(family, theta, 3, "bayes", np.random.SeedSequence(0))
