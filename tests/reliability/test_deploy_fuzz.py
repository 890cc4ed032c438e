"""Property-based fuzz of the deployment API: ``Agent.reset`` / ``act`` / ``act_each_prefix``
over shapes, dtypes, containers, values (NaN, ±inf, huge, negative, out-of-range indices, wrong ranks) and
orders of calls, on tiny random-weight policies.

The property: every call either returns a valid action (right shape, dtype and range) or raises
``ValueError`` / ``RuntimeError`` with a non-empty message — never another exception — and an input that an
independent oracle (below, written from the documented rules in ``contexts.py``) calls invalid is never
accepted.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from icprl_lightning.contexts import RewardContext, StepPreferenceContext
from icprl_lightning.methods.dpt import DPTModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig

S, N_ACTIONS, ACTION_DIM, MAX_CONTEXT = 2, 5, 3, 10
TINY = dict(state_dim=S, max_context=MAX_CONTEXT, backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
FUZZ = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

DTYPES = [torch.float16, torch.bfloat16, torch.float32, torch.float64, torch.int8, torch.int16, torch.int32,
          torch.int64, torch.uint8, torch.bool, torch.complex64]
SPECIAL = [float("nan"), float("inf"), -float("inf"), 1e30, -1e30, 3e38, 1e300, -1e-30, -7.0, 0.5, 2.0, -1.0,
           N_ACTIONS, 255, 1000, -(2**40)]


def _agents() -> dict:
    torch.manual_seed(0)
    return {"icpo_discrete": ICPOModule(action_dim=N_ACTIONS, discrete=True, **TINY).eval().make_agent(),
            "icpo_continuous": ICPOModule(action_dim=ACTION_DIM, discrete=False, **TINY).eval().make_agent(),
            "dpt_reward": DPTModule(action_dim=N_ACTIONS, discrete=True, **TINY).eval().make_agent(),
            "icpo_sampling": ICPOModule(action_dim=N_ACTIONS, discrete=True, **TINY).eval().make_agent(
                greedy=False, seed=0)}


AGENTS = _agents()


pytestmark = pytest.mark.usefixtures("one_thread")


def _layout(name: str) -> list[tuple[str, str]]:
    """(field, role) of the agent's context; role: float | index | label."""
    action = "float" if name == "icpo_continuous" else "index"
    if name == "dpt_reward":
        return [("states", "float"), ("actions", action), ("rewards", "float"), ("next_states", "float")]
    return [("states", "float"), ("actions", action), ("alt_actions", action), ("preferred", "label")]


def _shape(field: str, role: str, b: int, t: int, continuous: bool) -> tuple[int, ...]:
    if field in ("states", "next_states"):
        return (b, t, S)
    if role == "float" and continuous and "actions" in field:
        return (b, t, ACTION_DIM)
    return (b, t)


# ---- the oracle: is this field valid, judged from the final object alone -----------------------------------
def _valid(x, role: str, shape: tuple[int, ...]) -> bool:
    if isinstance(x, np.ndarray):
        x = torch.from_numpy(x)
    if not isinstance(x, torch.Tensor) or x.is_complex() or tuple(x.shape) != shape:
        return False
    if role == "float":
        return x.is_floating_point() and bool(torch.isfinite(x.to(torch.float32)).all())
    if role == "index":
        if x.is_floating_point() or x.dtype == torch.bool:
            return False
        v = x.to(torch.int64)
        return bool(((v >= 0) & (v < N_ACTIONS)).all())
    v = x.to(torch.float64)  # label
    return bool(((v == 0) | (v == 1)).all())


# ---- the generator: a field from a valid base, then a dtype, a rank change, injected values, a container ---
@st.composite
def field_value(draw, role: str, shape: tuple[int, ...]):
    g = torch.Generator().manual_seed(draw(st.integers(0, 2**16)))
    if role == "index":
        x = torch.randint(0, N_ACTIONS, shape, generator=g).double()
    elif role == "label":
        x = torch.randint(0, 2, shape, generator=g).double()
    else:
        x = torch.rand(shape, generator=g, dtype=torch.float64) * draw(st.sampled_from([1.0, 9.0, -3.0]))
    mutate = draw(st.sampled_from(["none"] * 12 + ["lossless", "lossless", "dtype", "values", "rank", "container",
                                                   "all"]))
    if mutate in ("values", "all") and x.numel():
        for _ in range(draw(st.integers(1, 3))):
            x.view(-1)[draw(st.integers(0, x.numel() - 1))] = draw(st.sampled_from(SPECIAL))
    if mutate in ("rank", "all"):
        how = draw(st.sampled_from(["drop", "extra", "row", "step", "scalar", "empty"]))
        x = {"drop": lambda: x.sum(-1) if x.dim() else x, "extra": lambda: x[..., None],
             "row": lambda: torch.cat([x, x[:1]]), "step": lambda: torch.cat([x, x[:, :1]], 1) if x.dim() > 1 else x,
             "scalar": lambda: torch.tensor(1.0, dtype=torch.float64), "empty": lambda: x[:0]}[how]()
    dtype = torch.float64 if role == "float" else torch.int64 if role == "index" else torch.float32
    if mutate in ("dtype", "all"):
        dtype = draw(st.sampled_from(DTYPES))
    elif mutate == "lossless":  # converted, not refused: float16/64 floats, narrower indices, bool labels
        dtype = draw(st.sampled_from({"float": [torch.float16, torch.float64, torch.bfloat16],
                                      "index": [torch.int8, torch.int16, torch.int32, torch.uint8],
                                      "label": [torch.bool, torch.int64, torch.float64, torch.uint8]}[role]))
    elif role == "float":
        dtype = draw(st.sampled_from([torch.float32, torch.float64]))
    with np.errstate(all="ignore"):
        x = x.to(dtype)
    container = "tensor"
    if mutate in ("container", "all"):
        container = draw(st.sampled_from(["numpy", "numpy", "list", "none", "string"]))
    elif mutate == "lossless":
        container = draw(st.sampled_from(["tensor", "numpy"]))
    if container == "numpy" and dtype != torch.bfloat16:
        return x.numpy()
    return {"list": x.tolist(), "none": None, "string": "states"}.get(container, x)


@st.composite
def context_case(draw):
    name = draw(st.sampled_from(sorted(AGENTS)))
    b = draw(st.sampled_from([1, 1, 2, 3, 3, 0]))
    t = draw(st.sampled_from([1, 2, 3, 5, MAX_CONTEXT, 0, MAX_CONTEXT + 1]))
    continuous = name == "icpo_continuous"
    fields, ok = {}, b >= 1 and 1 <= t <= MAX_CONTEXT
    for field, role in _layout(name):
        shape = _shape(field, role, b, t, continuous)
        fields[field] = draw(field_value(role, shape))
        ok = ok and _valid(fields[field], role, shape)
    cls = RewardContext if name == "dpt_reward" else StepPreferenceContext
    return name, cls(**fields), ok, b, t


def _check_action(agent, out: torch.Tensor, lead: tuple[int, ...]) -> None:
    spec = agent.policy.action_spec
    if spec.discrete:
        assert out.shape == lead and out.dtype == torch.int64
        assert bool(((out >= 0) & (out < spec.size)).all())
    else:
        assert out.shape == (*lead, spec.size) and out.dtype == torch.float32
        assert bool(torch.isfinite(out).all()) and bool((out.abs() <= 1).all())


def _expect_error(exc: BaseException) -> None:
    assert isinstance(exc, ValueError | RuntimeError), f"{type(exc).__name__}: {exc}"
    assert str(exc).strip(), "an error without a message"


def _act(agent, method: str, obs, b: int, t: int, obs_ok: bool) -> str:
    """One act / act_each_prefix call: a valid action, or the error its inputs call for. Returns the outcome."""
    try:
        out = getattr(agent, method)(obs)
    except Exception as e:  # noqa: BLE001 - the property is about which exceptions escape
        _expect_error(e)
        if isinstance(e, RuntimeError):  # only a non-finite output of finite (huge) inputs
            assert obs_ok and "not finite" in str(e), str(e)
            return "overflow"
        assert not obs_ok, f"valid obs refused: {e}"
        return "refused"
    assert obs_ok, f"invalid obs accepted: {obs!r}"
    _check_action(agent, out, (b,) if method == "act" else (b, t))
    return "action"


OUTCOMES: dict[str, int] = {}


def _count(key: str) -> None:
    OUTCOMES[key] = OUTCOMES.get(key, 0) + 1


@settings(max_examples=600, **FUZZ)
@given(case=context_case(), obs=st.data())
def test_reset_and_act_on_fuzzed_inputs(case, obs):
    name, ctx, ok, b, t = case
    agent = AGENTS[name]
    try:
        agent.reset(ctx)
    except Exception as e:  # noqa: BLE001
        _expect_error(e)
        assert isinstance(e, ValueError), f"reset raised {type(e).__name__}: {e}"
        assert not ok, f"valid context refused: {e}"
        fields = [f for f, _ in _layout(name)]
        assert any(str(e).startswith(f) for f in fields) or str(e).startswith("context holds"), str(e)
        _count("reset refused")
        with pytest.raises(RuntimeError, match="reset"):
            agent.act(torch.zeros(max(b, 1), S))
        return
    assert ok, f"invalid context accepted: {ctx!r}"
    _count("reset accepted")
    query = obs.draw(field_value("float", (b, S)))
    obs_ok = _valid(query, "float", (b, S))
    for method in ("act", "act_each_prefix"):
        _count(f"{method} {_act(agent, method, query, b, t, obs_ok)}")


OPS = ["reset", "reset_other_batch", "reset_invalid", "act", "act_wrong_batch", "act_each_prefix", "act_chunked"]


def _valid_context(name: str, b: int, t: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    continuous = name == "icpo_continuous"
    fields = {}
    for field, role in _layout(name):
        shape = _shape(field, role, b, t, continuous)
        if role == "index":
            fields[field] = torch.randint(0, N_ACTIONS, shape, generator=g)
        elif role == "label":
            fields[field] = torch.randint(0, 2, shape, generator=g).float()
        else:
            fields[field] = torch.rand(shape, generator=g) * 2 - 1
    return (RewardContext if name == "dpt_reward" else StepPreferenceContext)(**fields)


@settings(max_examples=300, **FUZZ)
@given(name=st.sampled_from(sorted(AGENTS)), ops=st.lists(st.sampled_from(OPS), min_size=1, max_size=8),
       seed=st.integers(0, 1000), fresh=st.booleans())
def test_orders_of_calls(name, ops, seed, fresh):
    agent = AGENTS[name]
    if fresh:  # a never-reset agent: act first must be the RuntimeError naming reset
        agent = type(agent)(agent.policy, greedy=agent.greedy)
    else:
        agent.reset(_valid_context(name, 2, 3, seed))
    state = None if fresh else (2, 3)  # (B, T) of the context the agent holds, None before any (good) reset
    for i, op in enumerate(ops):
        b = 1 + (seed + i) % 3
        t = 1 + (seed * 7 + i) % MAX_CONTEXT
        if op in ("reset", "reset_other_batch"):
            rows = b if op == "reset_other_batch" or state is None else state[0]
            agent.reset(_valid_context(name, rows, t, seed + i))
            state = (rows, t)
            _count("ops reset")
            continue
        if op == "reset_invalid":
            bad = _valid_context(name, b, t, seed + i)
            bad.states[0, 0, 0] = float("nan")
            with pytest.raises(ValueError, match="^states must hold finite values"):
                agent.reset(bad)
            state = None  # a failed reset leaves no context
            _count("ops reset refused")
            continue
        rows = (state[0] if state else 1) + (1 if op == "act_wrong_batch" else 0)
        obs = torch.rand(rows, S)
        if state is None:
            with pytest.raises(RuntimeError, match=r"reset\(context\)"):
                (agent.act_each_prefix if op in ("act_each_prefix", "act_chunked") else agent.act)(obs)
            _count("ops act before reset")
            continue
        if op == "act_wrong_batch":
            with pytest.raises(ValueError, match=rf"^obs must be a float tensor of shape \[B={state[0]}, S={S}\]"):
                agent.act(obs)
            _count("ops wrong batch")
        elif op == "act":
            _check_action(agent, agent.act(obs), (state[0],))
            _count("ops act")
        else:
            chunk = 1 if op == "act_chunked" else 32
            _check_action(agent, agent.act_each_prefix(obs, batch_chunk=chunk), state)
            _count("ops act_each_prefix")


@pytest.mark.parametrize("chunk", [0, -1, 2.5, True, "3", None])
def test_bad_batch_chunk_is_a_value_error(chunk):
    agent = AGENTS["icpo_discrete"]
    agent.reset(_valid_context("icpo_discrete", 2, 3, 0))
    with pytest.raises(ValueError, match="batch_chunk"):
        agent.act_each_prefix(torch.rand(2, S), batch_chunk=chunk)


def test_report_outcomes(capsys):
    """Not a check: prints how many fuzzed cases took each path (visible with ``-s``)."""
    with capsys.disabled():
        print("\nfuzz outcomes:", dict(sorted(OUTCOMES.items())))
