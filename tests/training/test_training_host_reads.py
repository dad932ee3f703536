"""Training reads nothing back from the device per step: a Lightning run of more steps reads as many tensors back
to the host as one of fewer (the loss, the style bank and the EMA's count are read once per run). The progress bar's
loss is a host copy taken every ``log_every_n_steps`` steps: Lightning turns what the bar shows into a number after
every batch, which for a value on the GPU is a wait for the device. EDGE's architecture (``null_music=output``)
keeps one read per step: the rows whose music is kept, so that its music encoder runs on those rows only (computing
all rows instead would draw other dropout masks and change the training). On a GPU (``-m gpu``) the count is
torch's own sync detection, which also sees copies from the host."""

from __future__ import annotations

import dataclasses
import warnings

import lightning as L
import pytest
import torch
from generation.gen_helpers import STYLE_DIM, tiny_spec
from host_reads import count_host_reads, differences

from dgsdp.style import StyleBank
from dgsdp.training import DanceDiffusion

READS_PER_STEP = {"input": 0, "output": 1}  # null_music: the default, EDGE's (its kept rows, see the docstring)


@pytest.fixture(autouse=True)
def _one_thread(one_torch_thread):
    """Tiny tensors: one torch thread (tests/conftest.py)."""


def tiny_training_model(null_music: str) -> DanceDiffusion:
    spec = tiny_spec()
    spec = dataclasses.replace(spec, model={**spec.model, "null_music": null_music, "dropout": 0.1})
    torch.manual_seed(0)
    model = DanceDiffusion(spec)
    model.set_style_bank(StyleBank(torch.eye(STYLE_DIM), torch.arange(STYLE_DIM), STYLE_DIM))
    return model


def fit(
    null_music: str, steps: int, log_every: int, accelerator: str = "cpu", precision: str = "32-true"
) -> DanceDiffusion:
    model = tiny_training_model(null_music)
    gen = torch.Generator().manual_seed(1)
    batches = [
        {"motion": torch.rand(4, 150, 151, generator=gen) * 2 - 1, "audio": torch.randn(4, 150, 35, generator=gen),
         "genre": torch.randint(0, STYLE_DIM, (4,), generator=gen)}
        for _ in range(steps)
    ]  # fmt: skip
    trainer = L.Trainer(
        max_steps=steps, accelerator=accelerator, devices=1, precision=precision, logger=False,
        enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False, log_every_n_steps=log_every,
    )  # fmt: skip
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*(log_every_n_steps|num_workers|val_dataloader|LeafSpec).*")
        trainer.fit(model, train_dataloaders=torch.utils.data.DataLoader(batches, batch_size=None))
    return model


@pytest.mark.parametrize("null_music", list(READS_PER_STEP))
def test_training_reads_back_nothing_per_step(null_music):
    runs = []
    for steps in (2, 5):
        with count_host_reads() as reads:
            fit(null_music, steps, log_every=50)  # the progress bar's loss is taken at step 0 only
        runs.append(reads)
    assert runs[0].total > 0  # the counting works
    grown = runs[1].distinct_tensors - runs[0].distinct_tensors
    assert grown == 3 * READS_PER_STEP[null_music], f"reads that grow with the steps: {differences(*runs)}"


def test_progress_bar_loss_is_a_host_copy_every_log_interval(monkeypatch):
    logged = []
    log = DanceDiffusion.log

    def record(self, name, value, *args, **kwargs):
        if name == "loss":
            logged.append((self.global_step, value.device.type, kwargs.get("prog_bar")))
        return log(self, name, value, *args, **kwargs)

    monkeypatch.setattr(DanceDiffusion, "log", record)
    fit("input", steps=5, log_every=2)
    assert logged == [(0, "cpu", True), (2, "cpu", True), (4, "cpu", True)]


@pytest.mark.gpu
@pytest.mark.parametrize("null_music", list(READS_PER_STEP))
def test_no_device_sync_per_training_step_on_cuda(null_music):
    """torch's sync detection counts every wait for the GPU, copies from the host included: 3 more steps make
    3 * READS_PER_STEP more."""
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    fit(null_music, 2, log_every=50, accelerator="gpu", precision="bf16-mixed")  # warm-up
    counts = []
    for steps in (2, 5):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            torch.cuda.set_sync_debug_mode("warn")
            try:
                fit(null_music, steps, log_every=50, accelerator="gpu", precision="bf16-mixed")
            finally:
                torch.cuda.set_sync_debug_mode("default")
        counts.append([f"{w.filename}:{w.lineno}" for w in caught if "synchroniz" in str(w.message)])
    grown = len(counts[1]) - len(counts[0])
    assert grown == 3 * READS_PER_STEP[null_music], f"syncs with 2 steps: {counts[0]}; with 5 steps: {counts[1]}"
