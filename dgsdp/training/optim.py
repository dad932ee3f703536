"""Adan (Xie et al., 2022), the optimiser of EDGE and DGSDP, as one multi-tensor update per step, and the EMA update.

The update is the one of the ``adan-pytorch`` package that the project trained with before (``adan_pytorch.Adan``):
the same arithmetic in the same order, element by element, the same state (``step``, ``m``, ``v``, ``n``,
``prev_grad`` per parameter) and the same settings per parameter group (``lr``, ``betas``, ``eps``,
``weight_decay``, ``restart_cond``), so an optimiser state saved by either resumes under the other and, on the CPU,
the weights after each step are equal to the last bit (tests/training/test_optim.py). What changes is how it runs:
that package loops over the parameters in Python, about fifteen small operations each, which on a GPU is thousands
of kernel launches a step for a model of a few hundred tensors; here each operation runs once over all the float32
and float64 parameters (``torch._foreach_*``: fused multi-tensor kernels on CUDA; on the CPU the same per-tensor
kernels as before). Half-precision parameters (``trainer.precision=bf16-true`` or ``16-true``) and groups with a
``restart_cond`` take adan-pytorch's own per-parameter loop: the multi-tensor kernels round bfloat16 and float16
products differently from the per-tensor ones, so the states would drift apart from the second step on.

:func:`ema_update` is the EMA step of :class:`torch.optim.swa_utils.AveragedModel` (``use_buffers=True`` with
``get_ema_multi_avg_fn``) without its two reads of a device tensor per step, which stall a GPU until it has caught up.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import torch

CPU_CHUNK_ELEMENTS = 1 << 18
"""On the CPU the parameters update in chunks of about this many elements, so that the step's temporaries stay in the
cache (one chunk over all of them streams every temporary through memory and runs slower than the per-parameter
loop); on CUDA all of them at once."""


def _chunks(params: list[torch.Tensor], elements: int | None) -> list[list[torch.Tensor]]:
    """``params`` in consecutive chunks of at most ``elements`` elements (a larger tensor alone; None: one chunk)."""
    if elements is None:
        return [params]
    out: list[list[torch.Tensor]] = [[]]
    size = 0
    for p in params:
        if out[-1] and size + p.numel() > elements:
            out.append([])
            size = 0
        out[-1].append(p)
        size += p.numel()
    return out


FOREACH_DTYPES = (torch.float32, torch.float64)
"""Parameter dtypes whose multi-tensor update rounds as adan-pytorch's per-parameter one does; the others (bfloat16,
float16) update one parameter at a time, with its operations."""

RestartCond = Callable[[dict[str, Any]], bool]


class Adan(torch.optim.Optimizer):
    """Adan with adan-pytorch's update (its defaults: ``betas`` (0.02, 0.08, 0.01), decoupled weight decay divided
    out after the step, bias correction of all three moments) run as multi-tensor operations.

    ``betas`` are adan-pytorch's (the weights of the new value: ``m <- (1 - b1) m + b1 g``), not the paper's
    (``1 - b``). ``restart_cond`` is adan-pytorch's too: called with a parameter's state after its step (``step``
    not yet counted up), true restarts the moments from the gradient and steps again. Sparse gradients are refused."""

    def __init__(
        self,
        params: Iterable[torch.Tensor] | Iterable[dict[str, Any]],
        lr: float = 1e-3,
        betas: tuple[float, float, float] = (0.02, 0.08, 0.01),
        eps: float = 1e-8,
        weight_decay: float = 0.0,
        restart_cond: RestartCond | None = None,
    ) -> None:
        betas = tuple(float(b) for b in betas)  # a config list becomes the tuple adan-pytorch stores
        if len(betas) != 3 or not all(0.0 <= b <= 1.0 for b in betas):
            raise ValueError(f"Adan needs three betas in [0, 1], got {betas}")
        if not (lr >= 0.0 and eps >= 0.0 and weight_decay >= 0.0):
            raise ValueError(f"Adan needs lr, eps and weight_decay >= 0, got {lr}, {eps}, {weight_decay}")
        if restart_cond is not None and not callable(restart_cond):
            raise ValueError(
                f"Adan's restart_cond must be a function of a parameter's state or None, got {restart_cond!r}"
            )
        # the keys of adan-pytorch's param groups, all of them: it reads each one at every step
        defaults = {"lr": lr, "betas": betas, "eps": eps, "weight_decay": weight_decay, "restart_cond": restart_cond}
        super().__init__(params, defaults)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Also a state saved before the groups held ``restart_cond`` (which adan-pytorch needs to resume it)."""
        super().__setstate__(state)
        for group in self.param_groups:
            group.setdefault("restart_cond", None)

    @torch.no_grad()
    def step(self, closure: Callable[[], Any] | None = None) -> Any:
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            # parameters at the same step count, on the same device and of the same dtype, update together
            batches: dict[tuple[int, torch.device, torch.dtype], list[torch.Tensor]] = {}
            for p in group["params"]:
                if p.grad is None:
                    continue
                if p.grad.is_sparse:
                    raise RuntimeError("Adan does not support sparse gradients")
                state = self.state[p]
                if len(state) == 0:
                    state["step"] = 0
                    for name in ("prev_grad", "m", "v", "n"):
                        state[name] = torch.zeros_like(p.grad)
                if group.get("restart_cond") is not None or p.dtype not in FOREACH_DTYPES:
                    self._update_one(group, p)
                    continue
                batches.setdefault((int(state["step"]), p.device, p.dtype), []).append(p)
            for (step, device, _), params in batches.items():
                for chunk in _chunks(params, None if device.type == "cuda" else CPU_CHUNK_ELEMENTS):
                    self._update(group, chunk, step)
        return loss

    def _update_one(self, group: dict[str, Any], p: torch.Tensor) -> None:
        """One step of ``p`` as adan-pytorch's loop takes it, operation for operation (the same rounding in every
        dtype), with its restart."""
        lr, eps, weight_decay = group["lr"], group["eps"], group["weight_decay"]
        beta1, beta2, beta3 = group["betas"]
        restart_cond = group.get("restart_cond")
        data, grad = p.detach(), p.grad.detach()
        state = self.state[p]
        step, m, v, n, prev_grad = state["step"], state["m"], state["v"], state["n"], state["prev_grad"]
        if step > 0:
            m.mul_(1 - beta1).add_(grad, alpha=beta1)
            grad_diff = grad - prev_grad
            v.mul_(1 - beta2).add_(grad_diff, alpha=beta2)
            next_n = (grad + (1 - beta2) * grad_diff) ** 2
            n.mul_(1 - beta3).add_(next_n, alpha=beta3)
        step += 1
        correct_m, correct_v, correct_n = (1 / (1 - (1 - b) ** step) for b in (beta1, beta2, beta3))

        def grad_step_() -> None:
            weighted_step_size = lr / (n * correct_n).sqrt().add_(eps)
            direction = m * correct_m + (1 - beta2) * v * correct_v
            data.addcmul_(weighted_step_size, direction, value=-1.0).div_(1 + weight_decay * lr)

        grad_step_()
        if restart_cond is not None and restart_cond(state):
            m.copy_(grad)
            v.zero_()
            n.copy_(grad**2)
            grad_step_()
        prev_grad.copy_(grad)
        state["step"] = step

    def _update(self, group: dict[str, Any], params: list[torch.Tensor], step: int) -> None:
        """One step of adan-pytorch's update for ``params``, all at ``step`` steps done before this one."""
        lr, eps, weight_decay = group["lr"], group["eps"], group["weight_decay"]
        beta1, beta2, beta3 = group["betas"]
        states = [self.state[p] for p in params]
        data = [p.detach() for p in params]
        grads = [p.grad.detach() for p in params]
        m, v, n, prev = ([s[k] for s in states] for k in ("m", "v", "n", "prev_grad"))
        if step > 0:
            torch._foreach_mul_(m, 1 - beta1)
            torch._foreach_add_(m, grads, alpha=beta1)
            grad_diff = torch._foreach_sub(grads, prev)
            torch._foreach_mul_(v, 1 - beta2)
            torch._foreach_add_(v, grad_diff, alpha=beta2)
            next_n = torch._foreach_mul(grad_diff, 1 - beta2)  # (grad + (1 - beta2) * grad_diff) ** 2
            torch._foreach_add_(next_n, grads)
            next_n = torch._foreach_pow(next_n, 2)
            torch._foreach_mul_(n, 1 - beta3)
            torch._foreach_add_(n, next_n, alpha=beta3)
            del grad_diff, next_n
        step += 1
        correct_m, correct_v, correct_n = (1 / (1 - (1 - b) ** step) for b in (beta1, beta2, beta3))
        # weighted step size: lr / (sqrt(n * correct_n) + eps), which torch computes as reciprocal(...) * lr
        size = torch._foreach_mul(n, correct_n)
        torch._foreach_sqrt_(size)
        torch._foreach_add_(size, eps)
        torch._foreach_reciprocal_(size)
        torch._foreach_mul_(size, lr)
        # m * correct_m + (1 - beta2) * v * correct_v
        direction = torch._foreach_mul(m, correct_m)
        scaled_v = torch._foreach_mul(v, 1 - beta2)
        torch._foreach_mul_(scaled_v, correct_v)
        torch._foreach_add_(direction, scaled_v)
        del scaled_v
        torch._foreach_addcmul_(data, size, direction, value=-1.0)
        torch._foreach_div_(data, 1 + weight_decay * lr)
        torch._foreach_copy_(prev, grads)
        for state in (self.state[p] for p in params):
            state["step"] = step


@torch.no_grad()
def ema_update(
    averaged: torch.optim.swa_utils.AveragedModel, model: torch.nn.Module, decay: float, first: bool
) -> None:
    """``averaged.update_parameters(model)`` for an AveragedModel of ``model`` with ``use_buffers=True`` and
    ``get_ema_multi_avg_fn(decay)``: the same arithmetic (a copy on the ``first`` update, then
    ``lerp(ema, current, 1 - decay)`` for floating-point tensors, ``ema * decay + current * (1 - decay)`` for the
    others) and the same ``n_averaged`` count, told by the caller whether this is the first update instead of read
    back from the device."""
    ema = [t.detach() for t in (*averaged.module.parameters(), *averaged.module.buffers())]
    current = [t.detach() for t in (*model.parameters(), *model.buffers())]
    if len(ema) != len(current):
        raise ValueError(f"the EMA copy has {len(ema)} tensors and the model {len(current)}")
    if first:
        torch._foreach_copy_(ema, current)
    else:
        floats = [i for i, t in enumerate(ema) if torch.is_floating_point(t) or torch.is_complex(t)]
        others = sorted(set(range(len(ema))) - set(floats))
        groups: dict[tuple[torch.device, torch.dtype], list[int]] = {}
        for i in floats:
            groups.setdefault((ema[i].device, ema[i].dtype), []).append(i)
        for indices in groups.values():
            torch._foreach_lerp_([ema[i] for i in indices], [current[i] for i in indices], 1 - decay)
        for i in others:
            ema[i].copy_(ema[i] * decay + current[i] * (1 - decay))
    averaged.n_averaged += 1


def ema_steps(averaged: torch.optim.swa_utils.AveragedModel) -> int:
    """How many EMA updates a (loaded) AveragedModel has had: read once, when training starts or resumes."""
    return int(averaged.n_averaged.item())


__all__ = ["Adan", "ema_steps", "ema_update"]
