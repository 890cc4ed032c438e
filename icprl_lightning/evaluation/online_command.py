"""``icprl evaluate online``: deploy I-PRL checkpoints online, asking for a comparison as they act.

    icprl evaluate online --config configs/icpo_darkroom.yaml --config configs/overlays/uniform_states.yaml \
        --ckpt runs/icprl/<id>/checkpoints/last.ckpt [--ckpt ...] [--rule action_uniform --rule top_two ...] \
        [--labels own|flipped|random] [--seeds 0 1] [--episodes 5] [--dqn dqn_from_scratch_darkroom.json] \
        [--out results/online_darkroom]
    icprl evaluate online --config configs/icpo_bandit.yaml --ckpt runs/icprl/<id>/checkpoints/last.ckpt \
        --seeds 0 1 2 [--rounds 200] [--n-problems 50] [--ad-ckpt <AD on duels>/checkpoints/last.ckpt ...]

The config's data section names the dataset (generated if missing) whose held-out tasks the checkpoints play
from an empty context. An MDP family (a ``TaskFamily`` whose oracle has ``utility``) is played as
``evaluation.online_mdp`` says: ``--episodes`` in a row, ``max_context / episodes`` queries each, answered by the
dataset's annotator, beside the offline contexts (and ``--dqn``'s learning curve); a dueling bandit as
``evaluation.online_bandit`` says: ``--rounds`` duels beside Double Thompson Sampling. ``--rule`` (repeat to
compare) is the pair rule; ``--labels flipped|random`` the online label diagnostic (answers inverted, or fair
coins). Several ``--ckpt`` are training seeds (rows: mean ± sem over them). ``--ad-ckpt`` (bandits) adds the row
``ad``: Algorithm Distillation on DTS's duels (``configs/ad_bandit.yaml``, docs/ad_bandit.md); with it ``--ckpt``
may be left out. ``--browser-session DIR`` (MDP): a person answers in the labelling page (``labelling/online.py``).

Prints the result as JSON; ``--out PATH`` also writes ``PATH.json``, ``PATH.md`` and ``PATH.png``.
``evaluate_online`` is the same run as a function.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.evaluation import online_bandit, online_mdp
from icprl_lightning.evaluation.pairing import fit_errors, is_bandit_data
from icprl_lightning.families.base import TaskFamily
from icprl_lightning.hub import load_model

MDP_ONLY = {"episodes": "--episodes", "quality": "--quality", "targets": "--targets", "dqn": "--dqn",
            "browser_session": "--browser-session"}
BANDIT_ONLY = {"rounds": "--rounds", "n_problems": "--n-problems", "ad_checkpoints": "--ad-ckpt"}


def evaluate_online(configs: Sequence[str | Path], checkpoints: Sequence[str | Path],
                    rules: Sequence[str] = ("action_uniform",), labels: str = "own",
                    seeds: Sequence[int] | None = None, episodes: int | None = None, quality: str | None = None,
                    targets: Sequence[float] | None = None, dqn: str | Path | None = None,
                    rounds: int | None = None, n_problems: int | None = None,
                    out: str | Path | None = None, ad_checkpoints: Sequence[str | Path] | None = None,
                    browser_session: str | None = None) -> dict[str, Any]:
    """``icprl evaluate online`` as a function: the same inputs as its options, the JSON it prints as a dict.

    ``configs`` stack as ``--config`` does; ``episodes``, ``quality``, ``targets`` and ``dqn`` apply to MDP
    families, ``rounds``, ``n_problems`` and ``ad_checkpoints`` to dueling bandits (a value given for the other
    kind is a ``ValueError`` naming its option). ``seeds`` default to 0 1 (MDP) or 0 (bandits). ``out`` writes
    ``<out>.json`` and ``<out>.png``. ``browser_session`` (MDP): a person answers in the browser
    (``labelling/online.py``), their answers logged in that directory.
    """
    if not configs:
        raise ValueError("--config: give the checkpoints' dataset config")
    if not checkpoints and not ad_checkpoints:
        raise ValueError("--ckpt: give at least one I-PRL checkpoint (or, on a dueling bandit, an --ad-ckpt)")
    checkpoints = [str(c) for c in checkpoints]
    dm = datamodule_from_config(*configs, progress=False)
    bandit = is_bandit_data(dm)
    given = {"episodes": episodes, "quality": quality, "targets": targets, "dqn": dqn, "rounds": rounds,
             "n_problems": n_problems, "ad_checkpoints": ad_checkpoints or None, "browser_session": browser_session}
    for key, option in (MDP_ONLY if bandit else BANDIT_ONLY).items():
        if given[key] is not None:
            raise ValueError(f"{option} applies to {'MDP families' if bandit else 'dueling bandits'}; the config's "
                             f"data are {'a dueling bandit' if bandit else 'an MDP family'}'s")
    for checkpoint in checkpoints:  # a policy of another family or size: one line naming both, before any data
        module = load_model(checkpoint)
        errors = fit_errors(module, dm)
        if errors:
            raise ValueError(f"--ckpt {checkpoint} does not fit the data of {' + '.join(map(str, configs))} "
                             f"({type(dm.family).__name__ if hasattr(dm, 'family') else type(dm).__name__}): "
                             f"{type(module).__name__} {'; '.join(errors)}")
    dm.prepare_data()
    if bandit:
        result = online_bandit.evaluate_online_bandit(
            dm, checkpoints, rules, labels, seeds if seeds is not None else (0,),
            rounds if rounds is not None else 200, n_problems, [str(c) for c in ad_checkpoints or ()])
    else:
        if not isinstance(getattr(dm, "family", None), TaskFamily):
            raise ValueError(f"the data of {', '.join(map(str, configs))} have no task family to answer queries at "
                             "the agent's states (recorded data have no simulator); use a task family's config")
        if not checkpoints:
            raise ValueError("--ckpt: give at least one I-PRL checkpoint")
        dm.setup("validate")
        person = None
        if browser_session is not None:
            from icprl_lightning.labelling.online import BrowserAnnotator

            person = BrowserAnnotator(browser_session)
        try:
            result = online_mdp.evaluate_online_mdp(
                dm, checkpoints, rules, labels, seeds if seeds is not None else (0, 1),
                episodes if episodes is not None else 5, quality or "medium", targets, dqn, person)
        finally:
            if person is not None:
                person.stop()
    result = {"configs": [str(c) for c in configs], **result}
    if out is not None:
        (online_bandit.OnlineBandit if bandit else online_mdp.OnlineMDP).write(result, out)
    return result
