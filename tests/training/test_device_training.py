"""Training on windows kept on the device (data.on_device=true) gives the host loader's weights to the last bit,
resumed mid-epoch too, and under trainer.overfit_batches."""

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


def test_overfit_batches_trains_on_the_first_windows_in_order(tmp_path, tiny_synthetic, monkeypatch, recwarn):
    """trainer.overfit_batches=2: on the device and on the host alike, every epoch trains on the first two batches
    of the training windows in their stored order (no shuffle, no Lightning warning that it turned shuffling off),
    to the same weights."""
    from dgsdp.training import DanceDiffusion

    seen: dict[str, list] = {}
    expected: list = []
    training_step = DanceDiffusion.training_step

    def record(self, batch, *args, **kwargs):
        dataset = self.trainer.datamodule.datasets["train"]
        expected[:] = [(dataset.sequences[i].name, start) for i, start in dataset.index[:8]]
        seen[self.trainer.datamodule.on_device].append(list(zip(batch["name"], batch["start"].tolist())))
        return training_step(self, batch, *args, **kwargs)

    monkeypatch.setattr(DanceDiffusion, "training_step", record)
    extra = ("+trainer.overfit_batches=2", "trainer.max_epochs=3", "trainer.max_steps=6")
    results = {}
    for on_device in ("true", "false"):
        seen[on_device] = []
        _, results[on_device] = run(tmp_path / on_device, tiny_synthetic, f"data.on_device={on_device}", *extra)
    assert len(expected) == 8 and len(set(expected)) == 8
    for on_device, batches in seen.items():
        assert len(batches) == 6, on_device  # 3 epochs of the 2 batches
        for epoch in range(3):
            assert batches[2 * epoch] + batches[2 * epoch + 1] == expected, (on_device, epoch)
    assert not [w for w in recwarn if "overfit" in str(w.message)]
    a, b = _state(results["true"]["checkpoint"]), _state(results["false"]["checkpoint"])
    assert a["global_step"] == b["global_step"] == 6
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
