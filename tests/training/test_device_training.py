"""Training on windows kept on the device (data.on_device=true) gives the host loader's weights to the last bit,
resumed mid-epoch too."""

import torch
from test_train import _state, run


def test_training_on_device_windows_gives_the_same_weights(tmp_path, tiny_synthetic):
    extra = (
        "trainer.max_steps=6", "model.speed_conditioning=true", "callbacks.model_checkpoint.every_n_train_steps=3",
        "+trainer.val_check_interval=3",
    )  # fmt: skip
    _, host = run(tmp_path / "host", tiny_synthetic, "data.on_device=false", *extra)
    _, device = run(tmp_path / "device", tiny_synthetic, "data.on_device=true", *extra)
    # and resumed mid-epoch from step 3 of a run on the device
    _, half = run(tmp_path / "half", tiny_synthetic, "data.on_device=true", *extra[1:], "trainer.max_steps=3")
    _, resumed = run(
        tmp_path / "resumed", tiny_synthetic, "data.on_device=true", *extra, f"ckpt_path={half['checkpoint']}"
    )
    a = _state(host["checkpoint"])
    for other in (device, resumed):
        b = _state(other["checkpoint"])
        assert a["global_step"] == b["global_step"] == 6
        for key in a["state_dict"]:
            assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    validation = {k: v for k, v in host["metrics"].items() if k.startswith("val")}
    assert validation and validation == {k: v for k, v in device["metrics"].items() if k.startswith("val")}
