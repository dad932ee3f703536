"""The multi-tensor Adan and EMA update give, on the CPU, exactly what the project trained with before them:
adan-pytorch's Adan and AveragedModel's EMA, compared bit for bit over several steps and in every float dtype; a
checkpoint of either resumes under the other; a whole tiny training run gives the same weights to the last bit."""

from __future__ import annotations

import copy
from collections.abc import Callable

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
    """Deterministic gradients of a step, in each parameter's dtype; the parameter named ``skip`` gets none (it is
    not updated)."""
    gen = torch.Generator().manual_seed(100 + step)
    for name, p in model.named_parameters():
        p.grad = None if name == skip else (torch.randn(p.shape, generator=gen) * (1 + step)).to(p.dtype)


def _assert_same_states(ours: torch.optim.Optimizer, ref: torch.optim.Optimizer, a, b) -> None:
    """Every parameter's Adan state equal to the last bit."""
    for x, y in zip(a.parameters(), b.parameters(), strict=True):
        sa, sb = ours.state[x], ref.state[y]
        assert sa["step"] == sb["step"]
        for k in ("m", "v", "n", "prev_grad"):
            assert sa[k].dtype == sb[k].dtype == x.dtype and torch.equal(sa[k], sb[k]), k


# float16 with the default eps: 1e-8 rounds to 0 there and adan-pytorch's first step is NaN (lr / 0 * 0)
DTYPES = [(torch.float32, 1e-8), (torch.float64, 1e-8), (torch.bfloat16, 1e-8), (torch.float16, 1e-4)]


@pytest.mark.parametrize(("dtype", "eps"), DTYPES, ids=lambda v: str(v).removeprefix("torch."))
@pytest.mark.parametrize("weight_decay", [0.0, 0.02])
def test_adan_equals_adan_pytorch_bit_for_bit(weight_decay, dtype, eps):
    """Also with bfloat16 and float16 weights (trainer.precision=bf16-true, 16-true), where multi-tensor products
    round differently from adan-pytorch's per-tensor ones."""
    ours_model, ref_model = _model().to(dtype), _model().to(dtype)
    kw = {"lr": 3e-3, "betas": (0.02, 0.08, 0.01), "eps": eps, "weight_decay": weight_decay}
    ours, ref = Adan(ours_model.parameters(), **kw), ReferenceAdan(ref_model.parameters(), **kw)
    for step in range(6):
        skip = "0.bias" if step == 2 else None  # a parameter without a gradient falls a step behind the others
        for m in (ours_model, ref_model):
            _grads(m, step, skip)
        ours.step()
        ref.step()
        for (name, a), b in zip(ours_model.named_parameters(), ref_model.parameters(), strict=True):
            assert torch.equal(a, b), f"step {step}: {name} differs by {(a.float() - b.float()).abs().max():g}"
    assert all(bool(p.isfinite().all()) for p in ours_model.parameters())
    _assert_same_states(ours, ref, ours_model, ref_model)
    assert ours.state[ours_model[0].bias]["step"] == 5  # it missed one step


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16], ids=lambda v: str(v).removeprefix("torch."))
@pytest.mark.parametrize("first", [Adan, ReferenceAdan], ids=["ours_then_adan_pytorch", "adan_pytorch_then_ours"])
def test_a_state_of_either_resumes_under_the_other(first, dtype):
    """The state dicts have the same layout and param-group keys: a state saved after three steps under one class,
    loaded into the other, takes the next steps exactly as the first class continuing would."""
    second = ReferenceAdan if first is Adan else Adan
    a = _model().to(dtype)
    opt_a = first(a.parameters(), lr=1e-3, weight_decay=0.02)
    for step in range(3):
        _grads(a, step)
        opt_a.step()
    b = _model().to(dtype)
    b.load_state_dict(a.state_dict())
    opt_b = second(b.parameters(), lr=1e-3, weight_decay=0.02)
    opt_b.load_state_dict(copy.deepcopy(opt_a.state_dict()))  # as a checkpoint holds it
    for step in range(3, 5):
        for m in (a, b):
            _grads(m, step)
        opt_a.step()
        opt_b.step()
        for x, y in zip(a.parameters(), b.parameters(), strict=True):
            assert torch.equal(x, y), f"step {step}"
    _assert_same_states(opt_a, opt_b, a, b)
    assert opt_b.state_dict()["state"][0]["step"] == 5


def test_a_state_saved_before_restart_cond_resumes_and_saves_it():
    """A state of ours from before its groups held ``restart_cond`` still loads, and saves again with it, so
    adan-pytorch resumes it and takes the step ours takes."""
    a, b, c = _model(), _model(), _model()
    ours = Adan(a.parameters(), lr=1e-3)
    _grads(a, 0)
    ours.step()
    old = copy.deepcopy(ours.state_dict())
    for group in old["param_groups"]:
        del group["restart_cond"]
    again = Adan(b.parameters(), lr=1e-3)
    again.load_state_dict(old)
    saved = again.state_dict()
    assert [g["restart_cond"] for g in saved["param_groups"]] == [None]
    c.load_state_dict(a.state_dict())
    ref = ReferenceAdan(c.parameters(), lr=1e-3)
    ref.load_state_dict(copy.deepcopy(saved))
    for m in (a, c):
        _grads(m, 1)
    ours.step()
    ref.step()  # no KeyError: 'restart_cond'
    assert all(torch.equal(x, y) for x, y in zip(a.parameters(), c.parameters(), strict=True))
    _assert_same_states(ours, ref, a, c)


def test_restart_cond_restarts_as_adan_pytorchs():
    """adan-pytorch's restart: when the condition holds after a step, the moments restart from the gradient and
    the parameter steps again (so the weights leave those of a run without it)."""
    ours_model, ref_model, plain_model = _model(), _model(), _model()
    calls: dict[str, list[int]] = {"ours": [], "ref": []}

    def cond(name: str) -> Callable[[dict], bool]:
        def restart(state: dict) -> bool:
            calls[name].append(state["step"])
            return state["step"] == 2

        return restart

    ours = Adan(ours_model.parameters(), lr=3e-3, weight_decay=0.02, restart_cond=cond("ours"))
    ref = ReferenceAdan(ref_model.parameters(), lr=3e-3, weight_decay=0.02, restart_cond=cond("ref"))
    plain = Adan(plain_model.parameters(), lr=3e-3, weight_decay=0.02)
    for step in range(4):
        for m in (ours_model, ref_model, plain_model):
            _grads(m, step)
        for opt in (ours, ref, plain):
            opt.step()
        assert all(torch.equal(x, y) for x, y in zip(ours_model.parameters(), ref_model.parameters(), strict=True))
        same_as_plain = all(
            torch.equal(x, y) for x, y in zip(ours_model.parameters(), plain_model.parameters(), strict=True)
        )
        assert same_as_plain == (step < 2), f"step {step}"
    _assert_same_states(ours, ref, ours_model, ref_model)
    n_params = len(list(ours_model.parameters()))
    assert calls["ours"] == calls["ref"] == [s for s in range(4) for _ in range(n_params)]


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="three betas"):
        Adan(_model().parameters(), betas=(0.1, 0.2))
    with pytest.raises(ValueError, match=">= 0"):
        Adan(_model().parameters(), lr=-1.0)
    with pytest.raises(ValueError, match="restart_cond"):
        Adan(_model().parameters(), restart_cond=0.5)


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
