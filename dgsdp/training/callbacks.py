"""Callbacks: periodic sample rendering during training."""

from __future__ import annotations

import logging
from pathlib import Path

import lightning as L
import numpy as np
import torch

from dgsdp.motion.skeleton import SMPL24, Skeleton

log = logging.getLogger(__name__)


class SampleRenderCallback(L.Callback):
    """Every ``every_n_epochs`` validation epochs, sample a few validation windows with the EMA model and write
    their joint positions (``.npy``) and a video under ``<run>/samples/epochNNNN/``. 0 switches it off."""

    def __init__(self, every_n_epochs: int = 0, num_samples: int = 2, sampling_steps: int = 50) -> None:
        self.every_n_epochs = every_n_epochs
        self.num_samples = num_samples
        self.sampling_steps = sampling_steps

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not self.every_n_epochs or trainer.sanity_checking or trainer.current_epoch % self.every_n_epochs:
            return
        if not trainer.is_global_zero or trainer.datamodule is None:
            return
        from dgsdp.generation import DanceGenerator, DanceRequest
        from dgsdp.sampling import SamplingSettings

        batch = next(iter(trainer.datamodule.val_dataloader()))
        n = min(self.num_samples, batch["motion"].shape[0])
        genre = batch["genre"][:n].to(pl_module.device)
        styles = pl_module.style_for(genre, random=False)
        frames = batch["motion"].shape[1]
        requests = [
            DanceRequest(
                frames,
                music=batch["audio"][i] if "audio" in batch else None,
                style=None if styles is None else styles[i],
                seed=i,
            )
            for i in range(n)
        ]
        # the project's one sampling path, on the model being trained (its own config: trusted)
        generator = DanceGenerator(
            pl_module, cache_dir=trainer.datamodule.cache_dir, device=pl_module.device, trusted=True
        )
        motion = torch.cat(generator.generate_many(requests, SamplingSettings(steps=self.sampling_steps)))
        folder = Path(trainer.default_root_dir) / "samples" / f"epoch{trainer.current_epoch:04d}"
        self.write(folder, motion, floor_z=float(pl_module.floor_height), skeleton=pl_module.skeleton)

    @staticmethod
    def write(folder: Path, motion: torch.Tensor, floor_z: float = 0.0, skeleton: Skeleton = SMPL24) -> None:
        from dgsdp.motion import pose_to_joints

        folder.mkdir(parents=True, exist_ok=True)
        joints = pose_to_joints(motion.float().cpu(), skeleton)
        for i, j in enumerate(joints):
            np.save(folder / f"sample{i}.npy", j.numpy())
            try:
                from dgsdp.export import render_video

                render_video(folder / f"sample{i}.mp4", j, floor_z=floor_z, skeleton=skeleton)
            except ImportError:  # rendering is optional for this hook
                pass
        log.info("wrote %d samples to %s", len(joints), folder)
