"""model.style_standardize in a trained checkpoint: the training bank's statistics in the weights and their EMA."""

import pytest
import torch


def test_a_trained_checkpoint_keeps_the_training_banks_statistics(tmp_path):
    from gen_helpers import train_tiny_checkpoint

    from dgsdp.trained import load_model

    model = load_model(train_tiny_checkpoint(tmp_path, ("model.style_standardize=1.0",)))
    bank = model.style_vectors.double()
    mean = bank.mean(0)
    for denoiser in (model.denoiser, model.ema.module):
        assert denoiser.style_standardize == 1.0
        torch.testing.assert_close(denoiser.style_mean.double(), mean)
        assert float(denoiser.style_scale) == pytest.approx(1.0 / float((bank - mean).pow(2).mean().sqrt()), rel=1e-5)
