"""The causal transformer: query masking semantics and KV-cached queries equal to the full forward."""

import torch

from icprl_lightning.contexts import ActionSpec, StepPreferenceContext
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.policy import InContextPolicy
from icprl_lightning.models.transformer import (
    ENCODE_ROWS,
    CausalTransformer,
    decode_attention,
    one_row_padded,
    query_mask,
)


def test_query_mask():
    m = query_mask(3, torch.tensor([0, 2]))
    expected = torch.tensor([
        [1, 0, 0, 0, 0],
        [1, 1, 0, 0, 0],
        [1, 1, 1, 0, 0],
        [0, 0, 0, 1, 0],  # sees no context, only itself
        [1, 1, 0, 0, 1],  # sees the first two context tokens
    ], dtype=torch.bool)
    assert torch.equal(m, expected)


def test_query_output_depends_only_on_visible_context():
    torch.manual_seed(0)
    net = CausalTransformer(TransformerConfig(n_layer=2, n_embd=16, n_head=2), max_context=10).eval()
    ctx, q = torch.randn(2, 6, 16), torch.randn(2, 3, 16)
    out = net(ctx, q, torch.tensor([2, 4, 6]))
    ctx2 = ctx.clone()
    ctx2[:, 4:] = torch.randn(2, 2, 16)  # change tokens only the last query sees
    out2 = net(ctx2, q, torch.tensor([2, 4, 6]))
    torch.testing.assert_close(out[:, :2], out2[:, :2])
    assert not torch.allclose(out[:, 2], out2[:, 2])


def test_cached_queries_equal_the_full_forward():
    torch.manual_seed(0)
    net = CausalTransformer(TransformerConfig(n_layer=3, n_embd=32, n_head=4), max_context=20).eval()
    ctx, q = torch.randn(4, 20, 32), torch.randn(4, 5, 32)
    full = net(ctx, q, torch.full((5,), 20))
    cached = net.query(net.encode(ctx), q)
    torch.testing.assert_close(cached, full, atol=1e-5, rtol=1e-5)



def test_encode_in_row_chunks_equals_the_whole_batch():
    """``encode`` runs the batch ENCODE_ROWS rows at a time: a ragged last chunk, single and multi-token queries."""
    torch.manual_seed(0)
    net = CausalTransformer(TransformerConfig(n_layer=2, n_embd=16, n_head=2), max_context=8).eval()
    b = 2 * ENCODE_ROWS + 3
    ctx = torch.randn(b, 8, 16)
    cache = net.encode(ctx)
    assert cache.length == 8 and cache.capacity == 9
    assert cache.keys[0].shape == (b, 2, 8, 9) and cache.values[0].shape == (b, 2, 9, 8)  # keys transposed
    for q in (torch.randn(b, 1, 16), torch.randn(b, 3, 16)):
        full = net(ctx, q, torch.full((q.shape[1],), 8))
        torch.testing.assert_close(net.query(cache, q), full, atol=1e-5, rtol=1e-5)

def test_policy_cache_agrees_for_discrete_and_continuous():
    torch.manual_seed(0)
    for spec in (ActionSpec(True, 5), ActionSpec(False, 4)):
        pol = InContextPolicy("step_preference", 3, spec,
                              backbone=TransformerConfig(n_layer=2, n_embd=16, n_head=2), max_context=12).eval()
        def acts(spec=spec):
            return torch.randint(0, 5, (2, 12)) if spec.discrete else torch.rand(2, 12, 4) * 2 - 1

        ctx = StepPreferenceContext(torch.randn(2, 12, 3), acts(), acts(), torch.randint(0, 2, (2, 12)).float())
        obs = torch.randn(2, 1, 3)
        torch.testing.assert_close(pol.query(pol.encode(ctx), obs), pol(ctx, obs, torch.tensor([12])), atol=1e-5,
                                   rtol=1e-5)
        out = pol.query(pol.encode(ctx), obs)
        assert out.shape == (2, 1, spec.size)
        if not spec.discrete:
            assert out.abs().max() <= 1


def test_preference_token_is_invariant_to_slot_order():
    """(a, a', y=1) and (a', a, y=0) are the same comparison and give the same output."""
    torch.manual_seed(0)
    pol = InContextPolicy("step_preference", 2, ActionSpec(True, 5), TransformerConfig(2, 16, 2), 8).eval()
    s, a, b = torch.randn(1, 8, 2), torch.randint(0, 5, (1, 8)), torch.randint(0, 5, (1, 8))
    y = torch.randint(0, 2, (1, 8)).float()
    obs = torch.randn(1, 1, 2)
    one = pol(StepPreferenceContext(s, a, b, y), obs, torch.tensor([8]))
    two = pol(StepPreferenceContext(s, b, a, 1 - y), obs, torch.tensor([8]))
    torch.testing.assert_close(one, two)


def test_one_query_row_padded_to_two_is_the_one_row_attention():
    """A compiled agent's act() attends with its one query row padded by a zero row (``one_row_padded``, so Inductor
    keeps the ATen matmuls): the first row is the one-row attention, masked or not, on cache views."""
    torch.manual_seed(0)
    q, k_t, v = torch.randn(3, 4, 1, 8), torch.randn(3, 4, 8, 9)[..., :7], torch.randn(3, 4, 9, 8)[:, :, :7]
    mask = torch.rand(3, 4, 1, 7) > 0.3
    mask[..., 0] = True
    for m in (None, mask):
        out = one_row_padded(q, k_t, v, m)
        assert out.shape == (3, 4, 1, 8)
        torch.testing.assert_close(out, decode_attention(q, k_t, v, m))
