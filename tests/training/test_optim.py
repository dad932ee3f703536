"""The multi-tensor Adan and EMA update give, on the CPU, exactly what the project trained with before them:
adan-pytorch's Adan and AveragedModel's EMA, compared bit for bit over several steps; a checkpoint of either resumes
under the other; a whole tiny training run gives the same weights to the last bit."""

from __future__ import annotations

import copy

import pytest
import torch
from adan_pytorch import Adan as ReferenceAdan
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from dgsdp.training import Adan
from dgsdp.training.optim import ema_steps, ema_update


def _model(seed: int = 0) -> torch.nn.Module:
    torch.manual_seed(seed)
    model = torch.nn.Sequential(torch.nn.Linear(7, 16), torch.nn.LayerNorm(16), torch.nn.GELU(), torch.nn.Linear(16, 3))
    model.register_buffer("counter", torch.zeros(2, dtype=torch.long))  # an integer buffer, as models may have
    model.register_buffer("stat", torch.ones(3))
    return model


def _grads(model: torch.nn.Module, step: int, skip: str | None = None) -> None:
    """Deterministic gradients of a step; the parameter named ``skip`` gets none (it is not updated)."""
    gen = torch.Generator().manual_seed(100 + step)
    for name, p in model.named_parameters():
        p.grad = None if name == skip else torch.randn(p.shape, generator=gen) * (1 + step)


@pytest.mark.parametrize("weight_decay", [0.0, 0.02])
def test_adan_equals_adan_pytorch_bit_for_bit(weight_decay):
    ours_model, ref_model = _model(), _model()
    kw = {"lr": 3e-3, "betas": (0.02, 0.08, 0.01), "eps": 1e-8, "weight_decay": weight_decay}
    ours, ref = Adan(ours_model.parameters(), **kw), ReferenceAdan(ref_model.parameters(), **kw)
    for step in range(6):
        skip = "0.bias" if step == 2 else None  # a parameter without a gradient falls a step behind the others
        for m in (ours_model, ref_model):
            _grads(m, step, skip)
        ours.step()
        ref.step()
        for (name, a), b in zip(ours_model.named_parameters(), ref_model.parameters(), strict=True):
            assert torch.equal(a, b), f"step {step}: {name} differs by {(a - b).abs().max().item():g}"
    for a, b in zip(ours_model.parameters(), ref_model.parameters(), strict=True):
        sa, sb = ours.state[a], ref.state[b]
        assert sa["step"] == sb["step"] and all(torch.equal(sa[k], sb[k]) for k in ("m", "v", "n", "prev_grad"))
    assert ours.state[ours_model[0].bias]["step"] == 5  # it missed one step


def test_a_state_of_either_resumes_under_the_other():
    """The state dicts have the same layout: an adan-pytorch state loaded into ours (and back) continues exactly."""
    a, b = _model(), _model()
    ref = ReferenceAdan(a.parameters(), lr=1e-3, weight_decay=0.02)
    for step in range(3):
        _grads(a, step)
        ref.step()
    b.load_state_dict(a.state_dict())
    ours = Adan(b.parameters(), lr=1e-3, weight_decay=0.02)
    ours.load_state_dict(copy.deepcopy(ref.state_dict()))
    for step in range(3, 5):
        for m in (a, b):
            _grads(m, step)
        ref.step()
        ours.step()
    assert all(torch.equal(x, y) for x, y in zip(a.parameters(), b.parameters(), strict=True))
    back = ReferenceAdan(_model().parameters(), lr=1e-3, weight_decay=0.02)
    back.load_state_dict(copy.deepcopy(ours.state_dict()))
    assert back.state_dict()["state"][0]["step"] == 5


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="three betas"):
        Adan(_model().parameters(), betas=(0.1, 0.2))
    with pytest.raises(ValueError, match=">= 0"):
        Adan(_model().parameters(), lr=-1.0)


def test_ema_update_equals_averaged_model_bit_for_bit():
    decay = 0.9
    model = _model()
    ref = AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True)
    ours = AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True)
    first = ema_steps(ours) == 0
    for step in range(4):
        with torch.no_grad():
            for p in model.parameters():
                p.add_(torch.randn(p.shape, generator=torch.Generator().manual_seed(step)))
            model.counter += 7
            model.stat.mul_(1.5)
        ref.update_parameters(model)
        ema_update(ours, model, decay, first=first)
        first = False
        for a, b in zip(ours.state_dict().values(), ref.state_dict().values(), strict=True):
            assert torch.equal(a, b)
    assert ema_steps(ours) == 4


def test_training_gives_the_same_weights_as_before(tmp_path, tiny_synthetic):
    """A few steps of a tiny training run with the multi-tensor Adan and EMA, and the same run with adan-pytorch's
    Adan and AveragedModel's update: every weight, EMA weight and optimiser state equal to the last bit."""
    from test_train import run

    _, ours = run(tmp_path / "ours", tiny_synthetic, "trainer.max_steps=4", "trainer.limit_val_batches=0")
    from dgsdp.training import DanceDiffusion as module_cls

    original = module_cls.optimizer_step

    used = set()

    def reference_step(self, *args, **kwargs):
        used.add(type(self.optimizers().optimizer))
        super(module_cls, self).optimizer_step(*args, **kwargs)
        self.ema.update_parameters(self.denoiser)

    import dgsdp.registry as registry

    try:
        module_cls.optimizer_step = reference_step
        registry.BUILTINS["optimizer"]["dgsdp.training.Adan"] = "adan_pytorch:Adan"
        _, ref = run(tmp_path / "ref", tiny_synthetic, "trainer.max_steps=4", "trainer.limit_val_batches=0")
    finally:
        module_cls.optimizer_step = original
        registry.BUILTINS["optimizer"]["dgsdp.training.Adan"] = "dgsdp.training.optim:Adan"
    assert used == {ReferenceAdan}  # the reference run trained with adan-pytorch's class
    a = torch.load(ours["checkpoint"], weights_only=True)
    b = torch.load(ref["checkpoint"], weights_only=True)
    assert a["state_dict"].keys() == b["state_dict"].keys()
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    sa, sb = a["optimizer_states"][0]["state"], b["optimizer_states"][0]["state"]
    assert sa.keys() == sb.keys()
    for i in sa:
        assert all(torch.equal(sa[i][k], sb[i][k]) for k in ("m", "v", "n", "prev_grad")) and sa[i]["step"] == 4
