"""Shared fixtures: W&B disabled, tiny DarkRoom datasets generated once per session."""

from __future__ import annotations

import os

import pytest
import torch
from factories import TPRL_TINY, darkroom_data  # noqa: E402

from icprl_lightning.data import PreferenceDataModule  # noqa: E402

os.environ.setdefault("WANDB_MODE", "disabled")


@pytest.fixture(scope="module")
def one_thread():
    """One torch thread for a module of tiny models (``pytestmark = pytest.mark.usefixtures("one_thread")``): on a
    shared 2-core machine a second intra-op thread only adds synchronization, many-fold for small MLPs and rollouts."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


TINY = dict(trajectories_per_task=6, val_trajectories_per_task=2, eval_contexts_per_task=1,
            calibration_episodes=4, n_train_tasks=80, n_test_tasks=20, progress=False, batch_size=8)


@pytest.fixture(scope="session")
def tiny_kwargs() -> dict:
    return dict(TINY)


@pytest.fixture(scope="session")
def data_root(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("data"))


@pytest.fixture(scope="session")
def tiny_ipref(data_root) -> PreferenceDataModule:
    dm = darkroom_data(context_kind="step_preference", root_dir=data_root, pairs=True, query_labels=True,
                            **TINY)
    dm.prepare_data()
    return dm


@pytest.fixture(scope="session")
def tiny_reward(data_root) -> PreferenceDataModule:
    dm = darkroom_data(context_kind="reward", root_dir=data_root, query_labels=True, **TINY)
    dm.prepare_data()
    return dm


# ---- tiny DarkRoom T-PRL data, shared by the data and method tests ------------------------------------

@pytest.fixture(scope="module")
def tprl(data_root) -> PreferenceDataModule:
    dm = darkroom_data("trajectory_preference", root_dir=data_root, pairs=True, query_labels=True, **TPRL_TINY)
    dm.prepare_data()
    return dm


@pytest.fixture(scope="module")
def tprl_rewards(data_root) -> PreferenceDataModule:
    dm = darkroom_data(context_kind="reward_trajectory", root_dir=data_root, **TPRL_TINY)
    dm.prepare_data()
    return dm
