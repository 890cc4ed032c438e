"""Are an I-PRL dataset's preferred and rejected actions apart on average, or only state by state?

For a stored continuous-action I-PRL dataset (``states``, ``actions``, ``alt_actions``, ``preferred``), prints
per action dimension the mean preferred action, the mean rejected action, their difference and the mean
|preferred − rejected| of a pair. A rejected side biased in one direction (a difference of means comparable
to the per-pair difference) would teach a pull-and-push loss such as ICPO's a state-independent direction.

    python scripts/ipref_action_balance.py data/metaworld_reach_sac-step_preference-<hash> [--split train]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def balance(split_dir: Path) -> dict[str, list[float]]:
    a, b = np.load(split_dir / "actions.npy"), np.load(split_dir / "alt_actions.npy")
    if a.ndim != 3:
        raise ValueError(f"{split_dir}: continuous actions [N, H, A] expected, got shape {list(a.shape)}")
    won = np.load(split_dir / "preferred.npy")[..., None] == 1
    preferred, rejected = np.where(won, a, b).reshape(-1, a.shape[-1]), np.where(won, b, a).reshape(-1, a.shape[-1])
    return {"mean_preferred": preferred.mean(0).tolist(), "mean_rejected": rejected.mean(0).tolist(),
            "difference_of_means": (preferred - rejected).mean(0).tolist(),
            "mean_abs_pair_difference": np.abs(preferred - rejected).mean(0).tolist()}


def main(args: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--split", default="train")
    ns = parser.parse_args(args)
    out = {k: [round(v, 3) for v in values] for k, values in balance(ns.dataset / ns.split).items()}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
