"""A callback that records, per rank, what a training run did: the windows of each batch, the diffusion
timesteps and noise drawn, the losses, the gradients of the first step (averaged by DDP, and each rank's own,
recomputed) and the final weights. Used by test_ddp.py through ``+callbacks.probe._target_=...``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
import torch

from dgsdp.training.module import step_seed


class Probe(L.Callback):
    def __init__(self, out: str) -> None:
        self.out = Path(out)
        self.steps: list[dict[str, Any]] = []
        self.grads: dict[str, torch.Tensor] = {}
        self._current: dict[str, Any] | None = None
        self._batch: dict[str, Any] | None = None
        self._recording = True
        self._banks: list[Any] = []

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        diffusion = pl_module.diffusion
        q_sample = diffusion.q_sample

        def recording_q_sample(x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
            if self._recording and pl_module.training and self._current is not None:
                self._current["t"] = t.detach().cpu().clone()
                self._current["noise"] = noise.detach().cpu().clone()
            return q_sample(x0, t, noise)

        diffusion.q_sample = recording_q_sample

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self._batch = batch
        self._current = {
            "step": trainer.global_step,
            "epoch": trainer.current_epoch,
            "windows": [(n, int(s)) for n, s in zip(batch["name"], batch["start"], strict=True)],
        }
        self.steps.append(self._current)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        self._current["loss"] = float(outputs["loss"])
        bank = pl_module.style_bank
        self._banks.append(bank)  # kept alive, so that a rebuilt bank cannot reuse an id
        self._current["style_bank_id"] = id(bank)

    def on_before_optimizer_step(self, trainer, pl_module, optimizer) -> None:
        if trainer.global_step != 0:
            return
        names = [n for n, p in pl_module.denoiser.named_parameters() if p.grad is not None]
        averaged = torch.cat([pl_module.denoiser.get_parameter(n).grad.flatten() for n in names])
        # this rank's own gradient, recomputed without DDP with the step's randomness (same seed, same draws)
        rng = torch.get_rng_state()
        self._recording = False
        seed = pl_module.spec.seed
        torch.manual_seed(step_seed(seed, 0, trainer.global_rank, trainer.world_size))
        loss = pl_module._loss(pl_module.denoiser, self._batch, train=True)["loss"]
        params = [pl_module.denoiser.get_parameter(n) for n in names]
        local = torch.cat([g.flatten() for g in torch.autograd.grad(loss, params)])
        self._recording = True
        torch.set_rng_state(rng)
        gathered = [torch.zeros_like(local) for _ in range(trainer.world_size)]
        torch.distributed.all_gather(gathered, local)
        self.grads = {"ddp": averaged.detach().clone(), "mean_of_local": torch.stack(gathered).mean(0)}
        self.grads["local"] = local.detach().clone()

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        state = {k: v.detach().cpu().clone() for k, v in pl_module.state_dict().items()}
        record = {"rank": trainer.global_rank, "world": trainer.world_size, "steps": self.steps, "grads": self.grads}
        torch.save({"record": record, "state": state}, self.out / f"rank{trainer.global_rank}.pt")
