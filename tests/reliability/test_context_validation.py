"""Invalid contexts are refused: at ``Agent.reset`` / ``act`` / ``act_each_prefix`` and at
dataset load, every error names the field; lossless dtype changes (float64, int32, bool labels, numpy) convert
and act exactly as the float32/int64 tensors do."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from factories import darkroom_data

from icprl_lightning.contexts import (
    ActionSpec,
    RewardContext,
    RewardTrajectoryContext,
    StepPreferenceContext,
    TrajectoryPreferenceContext,
)
from icprl_lightning.data.store import MANIFEST, DatasetError, write_dataset
from icprl_lightning.io import sha256
from icprl_lightning.methods.dit import DITModule
from icprl_lightning.methods.dpt import DP2TModule, DPTModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig

B, T, S, N_ACTIONS, ACTION_DIM, MAX_CONTEXT = 3, 4, 2, 5, 3, 10
TINY = dict(max_context=MAX_CONTEXT, backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
KINDS = ("step_preference", "trajectory_preference", "reward", "reward_trajectory")
MODULES = {"step_preference": (ICPOModule, {}), "trajectory_preference": (DP2TModule,
                                                                          {"context_kind": "trajectory_preference"}),
           "reward": (DPTModule, {}), "reward_trajectory": (DITModule, {})}
# the fields of each kind by role; "step" fields carry the T (H) axis
FLOATS = {"step_preference": ("states",), "reward": ("states", "rewards", "next_states"),
          "trajectory_preference": ("states_a", "states_b", "behavior_states"),
          "reward_trajectory": ("states", "rewards")}
ACTIONS = {"step_preference": ("actions", "alt_actions"), "reward": ("actions",), "reward_trajectory": ("actions",),
           "trajectory_preference": ("actions_a", "actions_b", "behavior_actions")}
LABELED = ("step_preference", "trajectory_preference")


def agent(kind: str, discrete: bool = True):
    cls, kw = MODULES[kind]
    torch.manual_seed(0)
    module = cls(state_dim=S, action_dim=N_ACTIONS if discrete else ACTION_DIM, discrete=discrete, **TINY, **kw)
    return module.eval().make_agent(greedy=True)


def context(kind: str, discrete: bool = True, t: int = T, seed: int = 0):
    """A valid context of ``kind`` (float32 states, int64 / float32 actions, float labels)."""
    g = torch.Generator().manual_seed(seed)

    def states():
        return torch.rand(B, t, S, generator=g) * 9

    def actions():
        if discrete:
            return torch.randint(0, N_ACTIONS, (B, t), generator=g)
        return torch.rand(B, t, ACTION_DIM, generator=g) * 2 - 1

    def rewards():
        return torch.rand(B, t, generator=g)

    if kind == "step_preference":
        return StepPreferenceContext(states(), actions(), actions(), torch.randint(0, 2, (B, t), generator=g).float())
    if kind == "reward":
        return RewardContext(states(), actions(), rewards(), states())
    if kind == "reward_trajectory":
        return RewardTrajectoryContext(states(), actions(), rewards())
    return TrajectoryPreferenceContext(states(), actions(), states(), actions(),
                                       torch.randint(0, 2, (B,), generator=g).float(), states(), actions())


def replace(ctx, **fields):
    values = {k: getattr(ctx, k) for k in ctx.__dataclass_fields__}
    return type(ctx)(**{**values, **fields})


def with_value(x: torch.Tensor, value, dtype=None) -> torch.Tensor:
    y = x.clone().to(dtype or x.dtype)
    y.view(-1)[1] = value
    return y


def _cases():
    """(kind, discrete, field, description, how to corrupt the field)."""
    out = []
    for kind in KINDS:
        for field in FLOATS[kind]:
            for label, value in (("nan", float("nan")), ("inf", float("inf")), ("-inf", -float("inf"))):
                out.append((kind, True, field, label, lambda x, v=value: with_value(x, v)))
            out.append((kind, True, field, "beyond-float32", lambda x: with_value(x, 1e300, torch.float64)))
            out.append((kind, True, field, "int-dtype", lambda x: x.long()))
            out.append((kind, True, field, "list", lambda x: x.tolist()))
        for field in ACTIONS[kind]:
            out.append((kind, True, field, "bool", lambda x: x.bool()))
            out.append((kind, True, field, "index-too-large", lambda x: with_value(x, N_ACTIONS)))
            out.append((kind, True, field, "index-negative", lambda x: with_value(x, -1)))
            out.append((kind, True, field, "float-indices", lambda x: x.float()))
            out.append((kind, False, field, "continuous-nan", lambda x: with_value(x, float("nan"))))
            out.append((kind, False, field, "continuous-int", lambda x: x.long()))
        if kind in LABELED:
            for value in (2, -1, 0.5, float("nan"), float("inf")):
                out.append((kind, True, "preferred", f"label-{value}", lambda x, v=value: with_value(x, v)))
            out.append((kind, True, "preferred", "int-label-2", lambda x: with_value(x.long(), 2)))
            out.append((kind, True, "preferred", "wrong-shape", lambda x: x[..., None]))
    return out


CASES = _cases()


@pytest.mark.parametrize("kind,discrete,field,label,corrupt", CASES,
                         ids=[f"{c[0]}-{c[2]}-{c[3]}" for c in CASES])
def test_bad_field_is_refused_by_name(kind, discrete, field, label, corrupt):
    a = agent(kind, discrete)
    good = context(kind, discrete)
    bad = replace(good, **{field: corrupt(getattr(good, field))})
    with pytest.raises(ValueError, match=rf"^{field}\b") as err:
        a.reset(bad)
    assert len(str(err.value)) > len(field) + 20
    with pytest.raises(RuntimeError, match="reset"):  # a failed reset leaves no context behind
        a.act(torch.rand(B, S))
    with pytest.raises(ValueError, match=rf"^{field}\b"):
        bad.validate(S, a.policy.action_spec)


@pytest.mark.parametrize("kind", KINDS)
def test_empty_context_is_refused(kind):
    a = agent(kind)
    empty = context(kind, t=0)
    first = "states_a" if kind == "trajectory_preference" else "states"
    axis = "H" if kind == "trajectory_preference" else "T"
    with pytest.raises(ValueError, match=rf"^{first} holds an empty context \({axis} = 0"):
        a.reset(empty)
    with pytest.raises(ValueError, match=rf"^{first} holds no contexts \(B = 0"):
        a.reset(empty.map(lambda x: x[:0]))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("bad", ["nan", "inf", "beyond-float32", "int", "wrong-batch", "list"])
def test_bad_obs_is_refused(kind, bad):
    a = agent(kind)
    a.reset(context(kind))
    obs = {"nan": with_value(torch.rand(B, S), float("nan")), "inf": with_value(torch.rand(B, S), float("inf")),
           "beyond-float32": with_value(torch.rand(B, S), -1e300, torch.float64),
           "int": torch.zeros(B, S, dtype=torch.long), "wrong-batch": torch.rand(B + 1, S),
           "list": torch.rand(B, S).tolist()}[bad]
    for call in (a.act, a.act_each_prefix):
        with pytest.raises(ValueError, match=r"^obs\b"):
            call(obs)


def test_behavior_trajectory_may_be_empty_only_when_absent():
    good = context("trajectory_preference")
    spec = ActionSpec(True, N_ACTIONS)
    with pytest.raises(ValueError, match=r"^behavior_states holds an empty context"):
        replace(good, behavior_states=good.behavior_states[:, :0], behavior_actions=good.behavior_actions[:, :0]
                ).validate(S, spec)
    assert replace(good, behavior_states=None, behavior_actions=None).validate(S, spec).behavior_states is None


def _lossless_variants(ctx, discrete: bool):
    """The same context as float64 / float16-free variants: float64 floats, int32/int16/uint8 indices, bool
    or int labels, numpy arrays."""
    def floats64(x):
        return x.double() if x.is_floating_point() else x

    variants = {"float64": ctx.map(floats64), "numpy": ctx.map(lambda x: x.numpy()),
                "float64-numpy": ctx.map(lambda x: floats64(x).numpy())}
    if discrete:
        for dtype in (torch.int32, torch.int16, torch.uint8):
            variants[str(dtype)] = ctx.map(lambda x, d=dtype: x if x.is_floating_point() else x.to(d))
    if hasattr(ctx, "preferred"):
        variants["bool-labels"] = replace(ctx, preferred=ctx.preferred.bool())
        variants["int-labels"] = replace(ctx, preferred=ctx.preferred.long())
    return variants


@pytest.mark.parametrize("discrete", [True, False])
@pytest.mark.parametrize("kind", KINDS)
def test_lossless_dtypes_convert_and_act_the_same(kind, discrete):
    a = agent(kind, discrete)
    ctx = context(kind, discrete)
    obs = torch.rand(B, S) * 9
    a.reset(ctx)
    expected, expected_prefix = a.act(obs), a.act_each_prefix(obs)
    for name, variant in _lossless_variants(ctx, discrete).items():
        a.reset(variant)
        for o in (obs, obs.double(), obs.numpy(), obs.double().numpy()):
            got = a.act(o)
            assert got.dtype == expected.dtype and torch.equal(got, expected), name
        assert torch.equal(a.act_each_prefix(obs.double()), expected_prefix), name
        normalized = variant.validate(S, a.policy.action_spec)
        for field in ctx.__dataclass_fields__:
            x = getattr(normalized, field)
            assert x.dtype in (torch.float32, torch.int64), (name, field, x.dtype)


def test_validate_returns_a_normalized_copy():
    ctx = context("step_preference").map(lambda x: x.double() if x.is_floating_point() else x.int())
    ctx = replace(ctx, preferred=ctx.preferred.bool())
    out = ctx.validate(S, ActionSpec(True, N_ACTIONS))
    assert (out.states.dtype, out.actions.dtype, out.preferred.dtype) == (torch.float32, torch.int64, torch.float32)
    assert (ctx.states.dtype, ctx.actions.dtype, ctx.preferred.dtype) == (torch.float64, torch.int32, torch.bool)
    assert set(out.preferred.unique().tolist()) <= {0.0, 1.0}


def test_huge_finite_inputs_are_an_error_not_a_nan_action():
    for discrete in (True, False):
        a = agent("step_preference", discrete)
        ctx = context("step_preference", discrete)
        a.reset(replace(ctx, states=torch.full_like(ctx.states, 3e38)))
        with pytest.raises(RuntimeError, match="not finite"):
            a.act(torch.full((B, S), 3e38))


# ---- at dataset load ----------------------------------------------------------------------------------------
def _arrays(n: int = 4, t: int = 3) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {"states": rng.random((n, t, 2), dtype=np.float32), "actions": rng.integers(0, 5, (n, t)).astype(np.int8),
            "alt_actions": rng.integers(0, 5, (n, t)).astype(np.int8),
            "preferred": rng.integers(0, 2, (n, t)).astype(np.uint8),
            "task_index": np.repeat(np.arange(n // 2), 2).astype(np.int32), "quality": np.zeros(n, np.int8)}


def _corrupt(arrays: dict[str, np.ndarray], field: str, value) -> None:
    if value == "empty":
        for k in ("states", "actions", "alt_actions", "preferred"):
            arrays[k] = arrays[k][:, :0]
        return
    arrays[field] = arrays[field].copy()
    arrays[field].reshape(-1)[2] = value


@pytest.mark.parametrize("split", ["train", "val"])
@pytest.mark.parametrize("field,value,message", [
    ("preferred", 2, r"must hold only 0 or 1 .*found \[2\]"),
    ("states", np.nan, "NaN"),
    ("states", np.inf, "inf"),
    ("actions", 5, r"outside \[0, 5\)"),
    ("alt_actions", -1, r"outside \[0, 5\)"),
    ("states", "empty", r"T = 0"),
])
def test_setup_refuses_a_dataset_with_bad_values(tmp_path, split, field, value, message):
    dm = darkroom_data(data_dir=str(tmp_path / "ds"), progress=False, n_train_tasks=2, n_test_tasks=2)
    splits = {"train": _arrays(), "val": _arrays()}
    _corrupt(splits[split], field, value)
    write_dataset(dm.path, splits, dm.generator_config())
    with pytest.raises(DatasetError, match=message) as err:
        dm.setup("fit")
    text = str(err.value)
    assert f"split {split!r}" in text and f"field {field!r}" in text and str(dm.path) in text, text
    assert "To fix" in text


def test_setup_accepts_valid_data_once(tmp_path, monkeypatch):
    dm = darkroom_data(data_dir=str(tmp_path / "ds"), progress=False, n_train_tasks=2, n_test_tasks=2)
    write_dataset(dm.path, {"train": _arrays(), "val": _arrays()}, dm.generator_config())
    dm.setup("fit")
    import icprl_lightning.data.datamodule as datamodule

    calls = []
    monkeypatch.setattr(datamodule, "check_dataset", lambda *a, **k: calls.append(a))
    dm.setup("validate")  # the same loaded dataset: not checked again
    assert calls == []


def test_generated_dataset_passes_and_a_corrupted_label_file_is_refused(tiny_ipref, tmp_path):
    tiny_ipref.setup("fit")  # a generated dataset passes (and the DataModules of the other tests rely on it)
    copy = tmp_path / "copy"
    shutil.copytree(tiny_ipref.path, copy)
    rel = "train/preferred.npy"
    labels = np.load(copy / rel)
    labels.reshape(-1)[7] = 2
    np.save(copy / rel, labels)
    manifest = json.loads((copy / MANIFEST).read_text())  # fix the checksum so only the value check can catch it
    manifest["files"][rel].update(sha256=sha256(copy / rel), bytes=(copy / rel).stat().st_size)
    (copy / MANIFEST).write_text(json.dumps(manifest))
    dm = darkroom_data(data_dir=str(copy), root_dir=tiny_ipref.root_dir, pairs=True, query_labels=True,
                       trajectories_per_task=6, val_trajectories_per_task=2, eval_contexts_per_task=1,
                       calibration_episodes=4, n_train_tasks=80, n_test_tasks=20, progress=False)
    with pytest.raises(DatasetError, match=r"split 'train', field 'preferred'.*found \[2\]"):
        dm.setup("fit")
