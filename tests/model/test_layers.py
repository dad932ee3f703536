"""The denoiser's building blocks: rotary positions, the CPU dropout mask, and attention's training and fused
self-attention paths."""

import math

import pytest
import torch
import torch.nn.functional as F

from dgsdp.model.layers import Attention, Dropout, RotaryEmbedding, dropout

KEPT_SCALE = 65536 / (65536 - 6554)  # p = 0.1 drops 6554 of the 65536 16-bit values


def test_cpu_dropout_drops_a_tenth_and_keeps_the_expectation():
    torch.manual_seed(0)
    x = torch.full((400, 1000), 2.0)
    y = dropout(x, 0.1, training=True)
    dropped = (y == 0).double().mean().item()
    # binomial spread of the fraction over 400,000 elements: sqrt(0.1 * 0.9 / 4e5) = 0.00047
    assert abs(dropped - 6554 / 65536) < 5 * 0.00047
    assert torch.allclose(y[y != 0], torch.tensor(2.0 * KEPT_SCALE))
    assert abs(y.double().mean().item() - 2.0) < 5 * 2.0 * KEPT_SCALE * 0.00047


def test_cpu_dropout_masks_differ_between_calls_and_repeat_with_the_seed():
    x = torch.ones(64, 64)
    torch.manual_seed(1)
    a, b = dropout(x, 0.5, True), dropout(x, 0.5, True)
    torch.manual_seed(1)
    assert torch.equal(dropout(x, 0.5, True), a)
    assert not torch.equal(a, b)
    # the four 16-bit lanes of each 64-bit draw are independent: every lane drops about half
    for lane in range(4):
        assert 0.4 < (a.flatten()[lane::4] == 0).double().mean().item() < 0.6


def test_cpu_dropout_gradient_is_the_mask_times_the_scale():
    torch.manual_seed(2)
    x = torch.randn(50, 30, requires_grad=True)
    y = dropout(x, 0.1, True)
    y.sum().backward()
    expected = (y != 0).float() * KEPT_SCALE
    assert torch.allclose(x.grad, expected)


def test_dropout_off_in_eval_and_all_dropped_at_one():
    x = torch.randn(8, 8)
    module = Dropout(0.3).eval()
    assert module(x) is x
    assert torch.equal(dropout(x, 1.0, True), torch.zeros_like(x))
    assert dropout(x, 0.0, True) is x


@pytest.mark.parametrize("rotary,placement", [(False, "qk"), (True, "qk"), (True, "input")])
def test_training_attention_path_equals_the_inference_path_without_drops(rotary, placement):
    """With a dropout too small to drop anything (p < 1/131072 rounds to no 16-bit value), the training path
    (attention weights computed explicitly for the CPU mask) gives the inference path's output (SDPA)."""
    torch.manual_seed(3)
    attn = Attention(32, 4, dropout=1e-6, rotary=rotary, rotary_placement=placement)
    x, memory = torch.randn(2, 10, 32), torch.randn(2, 12, 32)
    for mem in (None, memory):
        trained = attn.train()(x, mem)
        assert torch.allclose(trained, attn.eval()(x, mem), atol=1e-5)


def test_self_attention_without_rotary_matches_reference():
    torch.manual_seed(4)
    attn = Attention(32, 4, dropout=0.0, rotary=False).eval()
    x = torch.randn(2, 10, 32)
    q = F.linear(x, attn.q.weight, attn.q.bias)
    k, v = F.linear(x, attn.kv.weight, attn.kv.bias).chunk(2, dim=-1)
    q, k, v = (a.reshape(2, 10, 4, 8).transpose(1, 2) for a in (q, k, v))
    weights = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(8), dim=-1)
    expected = attn.out((weights @ v).transpose(1, 2).reshape(2, 10, 32))
    assert torch.allclose(attn(x), expected, atol=1e-5)


def _rotated_by_hand(x: torch.Tensor, start: int) -> torch.Tensor:
    """Each pair (x1, x2) of channels at position p turned by p * 10000^(-2i/D), in float64."""
    x = x.double()
    d = x.shape[-1]
    angle = torch.arange(start, start + x.shape[-2], dtype=torch.float64)[:, None] * 10000.0 ** (
        -torch.arange(0, d, 2, dtype=torch.float64) / d
    )
    x1, x2 = x[..., 0::2], x[..., 1::2]
    out = torch.empty_like(x)
    out[..., 0::2] = x1 * angle.cos() - x2 * angle.sin()
    out[..., 1::2] = x1 * angle.sin() + x2 * angle.cos()
    return out


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-5), (torch.bfloat16, 5e-2)])
@pytest.mark.parametrize("start", [0, 7])
def test_rotary_turns_each_pair_by_its_angle(dtype, tol, start):
    """float32/64 go through the complex product, bf16 through the real formula (the angles are float32 in every
    case); both turn the pairs, also on a per-head view (not contiguous) and from a start position."""
    torch.manual_seed(5)
    rotary = RotaryEmbedding(16)
    x = torch.randn(2, 12, 3, 16).transpose(1, 2).to(dtype)  # (B, H, T, Dh) view of (B, T, H, Dh)
    for mode in (rotary.train(), rotary.eval(), rotary.eval()):  # the eval tables are cached on the second call
        assert torch.allclose(mode(x, start).double(), _rotated_by_hand(x, start), atol=tol)


def test_rotary_gradient_is_the_inverse_turn():
    torch.manual_seed(6)
    rotary = RotaryEmbedding(16).train()
    x = torch.randn(3, 10, 16, requires_grad=True)
    g = torch.randn(3, 10, 16)
    rotary(x).backward(g)
    # a rotation's transpose is its inverse: turning the gradient back gives back x's turn of g's length
    assert torch.allclose(_rotated_by_hand(x.grad, 0), g.double(), atol=1e-5)
