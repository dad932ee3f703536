"""The GPU speed path on a CUDA device (``-m gpu``): bf16 autocast, TF32 matmuls, torch.compile, pinned
persistent loader workers and activation checkpointing in one tiny run of the real entry point."""

import pytest
import torch
from test_train import run


@pytest.mark.gpu
def test_tiny_run_with_every_speed_setting_on_cuda(tmp_path, tiny_synthetic):
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    cfg, result = run(
        tmp_path, tiny_synthetic, "trainer=gpu", "trainer.accelerator=gpu", "trainer.max_steps=3",
        "trainer.limit_val_batches=0", "compile=true", "data.num_workers=2", "data.pin_memory=true", "data.persistent_workers=true",
        "++model.gradient_checkpointing=true",
    )  # fmt: skip
    assert cfg.trainer.precision == "bf16-mixed"
    assert result["global_step"] == 3
    assert torch.isfinite(torch.tensor(result["metrics"]["train/loss"]))
    assert torch.get_float32_matmul_precision() == "high"
