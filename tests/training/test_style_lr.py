"""optimizer.style_lr_scale: the style's ways in (Style Modulation's projection, the null style) train at that
multiple of the learning rate and the rest of the denoiser as before. Checked on the first step of tiny runs from
the same weights and batch: the rest bit for bit, the style's weights against Adan's step worked out from two runs
and predicted for a third."""

from __future__ import annotations

import pytest
import torch

from dgsdp.errors import ConfigError
from dgsdp.training.module import style_lr_scale

LR, WD = 1e-3, 0.02  # the tiny runs' learning rate; Adan's weight decay (conf/optimizer/adan.yaml)


def _one_step(tmp_path, root, scale: float | None) -> tuple[dict[str, torch.Tensor], dict, list[float]]:
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.train import train
    from dgsdp.safety.checkpoint_file import load_checkpoint

    overrides = [
        "debug=tiny", f"data.root={root}", "data.synthetic=null", f"paths.cache_dir={tmp_path / 'cache'}",
        "data.progress=false", "logger=none", "~callbacks.progress", "trainer.max_steps=1",
        "trainer.limit_val_batches=0", f"optimizer.lr={LR}", "style=onehot",
    ] + ([] if scale is None else [f"+optimizer.style_lr_scale={scale}"])  # fmt: skip
    record = load_checkpoint(train(compose_config("train", overrides, output_dir=tmp_path / f"x{scale}"))["checkpoint"])
    weights = {k[len("denoiser.") :]: v for k, v in record["state_dict"].items() if k.startswith("denoiser.")}
    return weights, record, [g["lr"] for g in record["optimizer_states"][0]["param_groups"]]


def test_the_style_trains_at_its_own_rate_and_the_rest_as_before(tmp_path):
    from dgsdp.data.synthetic import generate_synthetic_aistpp

    root = generate_synthetic_aistpp(tmp_path / "data", seed=0, sequences_per_genre=2, seconds=6.0, num_ignored=0)
    plain, _, plain_lrs = _one_step(tmp_path, root, None)
    ten, record, lrs = _one_step(tmp_path, root, 10.0)
    three, _, _ = _one_step(tmp_path, root, 3.0)
    assert plain_lrs == [LR] and lrs == pytest.approx([LR, 10 * LR])  # without the key: one group, as before
    assert record["hyper_parameters"]["optimizer"]["style_lr_scale"] == 10.0
    parts = ("modulations.", "null_style", "style_concat_proj.", "style_film_proj.")
    style = {n for n in plain if n.startswith(parts)}
    assert len(record["optimizer_states"][0]["param_groups"][1]["params"]) == len(style)
    # the rest bit for bit; the null style has no gradient without style dropout, so no step moves it
    style -= {"null_style"}
    assert {n for n in plain if not torch.equal(plain[n], ten[n])} == style and "modulations.0.fc.weight" in style
    # Adan's decoupled step: p1 = (p0 - lr u) / (1 + lr wd). The runs at rates lr and 10 lr give p0 and u; the run at
    # 3 lr must land where they predict.
    for name in sorted(style):
        a, b = (1 + LR * WD) * plain[name].double(), (1 + 10 * LR * WD) * ten[name].double()
        u = (a - b) / (9 * LR)
        p0 = a + LR * u
        expected = (p0 - 3 * LR * u) / (1 + 3 * LR * WD)
        assert (three[name].double() - plain[name].double()).abs().max() > 1e-5, name  # the rates moved it apart
        torch.testing.assert_close(three[name].double(), expected, rtol=1e-5, atol=1e-6, msg=name)


@pytest.mark.parametrize("value", [0, -1.0, "fast", True, 1e5])
def test_bad_scales_are_refused(value):
    with pytest.raises(ConfigError, match="style_lr_scale must be a positive number"):
        style_lr_scale({"style_lr_scale": value})
    assert style_lr_scale({}) == 1.0 and style_lr_scale({"style_lr_scale": 3}) == 3.0
