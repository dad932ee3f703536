"""Guidance distillation: the student's guidance input, the teacher's guided target against the sampler's own
guidance, one pass per sampling step, a real distillation run through train.py, and its configuration errors."""

import dataclasses

import pytest
import torch
from hydra.utils import instantiate
from test_train import run

from dgsdp.cli.evaluate import run_info
from dgsdp.cli.train import audio_encoder_from_config
from dgsdp.errors import ConfigError
from dgsdp.model import DanceDenoiser
from dgsdp.sampling import Sampler
from dgsdp.sampling.sampler import Condition, Guidance
from dgsdp.trained import load_model
from dgsdp.trained.model import TrainedModel
from dgsdp.trained.spec import RunSpec
from dgsdp.training.distill import DistillSettings, GuidanceDistillation

SIZES = {"d_model": 16, "n_layers": 2, "n_heads": 2, "ff_dim": 32, "music_encoder_layers": 1, "seq_len": 12}


def tiny_denoiser(**kwargs) -> DanceDenoiser:
    torch.manual_seed(0)
    return DanceDenoiser(audio_dim=6, style_dim=4, dropout=0.0, **SIZES, **kwargs).eval()


def inputs(b: int, n: int):
    g = torch.Generator().manual_seed(1)
    x_t, t = torch.randn(b, n, 151, generator=g), torch.randint(0, 1000, (b,), generator=g)
    return x_t, t, torch.randn(b, n, 6, generator=g), torch.randn(b, 4, generator=g)


def test_untrained_student_is_the_teachers_conditional_model():
    teacher = tiny_denoiser()
    student = tiny_denoiser(guidance_inputs=1)
    missing, unexpected = student.load_state_dict(teacher.state_dict(), strict=False)
    assert sorted(missing) == ["guidance_proj.bias", "guidance_proj.weight"] and not unexpected
    x_t, t, music, style = inputs(3, 12)
    want = teacher(x_t, t, music, style)
    for w in (0.0, 1.0, 2.5):
        got = student(x_t, t, music, style, guidance=torch.full((3, 1), w))
        torch.testing.assert_close(got, want, rtol=0, atol=1e-6)
    with torch.no_grad():
        student.guidance_proj.weight.normal_()
    a = student(x_t, t, music, style, guidance=torch.full((3, 1), 0.0))
    b = student(x_t, t, music, style, guidance=torch.full((3, 1), 2.5))
    assert (a - b).abs().max() > 1e-3  # once trained, the weight is heard


def test_guidance_input_errors():
    x_t, t, music, style = inputs(2, 12)
    with pytest.raises(ValueError, match=r"needs guidance weights \(2, 1\), got None"):
        tiny_denoiser(guidance_inputs=1)(x_t, t, music, style)
    with pytest.raises(ValueError, match=r"got \(2, 2\)"):
        tiny_denoiser(guidance_inputs=1)(x_t, t, music, style, guidance=torch.ones(2, 2))
    with pytest.raises(ValueError, match="takes none"):
        tiny_denoiser()(x_t, t, music, style, guidance=torch.ones(2, 1))
    with pytest.raises(ValueError, match="guidance_inputs must be one of"):
        tiny_denoiser(guidance_inputs=3)


def _teacher_and_student(style_guidance: bool) -> tuple[TrainedModel, GuidanceDistillation]:
    spec = RunSpec.from_groups(audio_dim=6, style_dim=4, style_bank_size=3, n_genres=3, dropout=0.0, **SIZES)
    if style_guidance:
        spec = dataclasses.replace(spec, conditioning=dataclasses.replace(spec.conditioning, style_drop_prob=0.3))
    torch.manual_seed(0)
    teacher = TrainedModel(spec).eval()
    with torch.no_grad():  # a learned null style and music that differ from a zero input
        for p in teacher.ema.module.parameters():
            p.normal_(0, 0.2)
    n = 2 if style_guidance else 1
    student_spec = dataclasses.replace(spec, model={**spec.model, "guidance_inputs": n})
    return teacher, GuidanceDistillation(student_spec, teacher, max_weight=3.0)


@pytest.mark.parametrize("style_guidance", [False, True])
def test_guided_target_is_the_samplers_guidance(style_guidance):
    """The target, formed with per-row weights in one batch, equals the sampler's guided x0, row by row."""
    teacher, student = _teacher_and_student(style_guidance)
    x_t, t, music, style = inputs(3, 12)
    weights = torch.tensor([[0.0, 1.0], [1.0, 0.5], [2.5, 2.0]])[:, : 2 if style_guidance else 1]
    target = student.guided_teacher(x_t, t, music, style, weights)
    sampler = Sampler(teacher.ema.module, teacher.diffusion, style_guidance=style_guidance, clip_x0=False)
    for i in range(3):
        w = weights[i].tolist()
        guidance = Guidance(w[0], w[-1] if style_guidance else 1.0)
        want = sampler.predict_x0(x_t[i : i + 1], t[i : i + 1], Condition(music[i : i + 1], style[i : i + 1]), guidance)
        torch.testing.assert_close(target[i : i + 1], want, rtol=1e-5, atol=1e-5)
    # and the guidance mattered: the target is not the conditional prediction
    conditional = teacher.ema.module(x_t, t, music, style)
    assert (target[2] - conditional[2]).abs().max() > 1e-2


def test_student_starts_from_the_teachers_weights_and_samples_in_one_pass():
    teacher, student = _teacher_and_student(style_guidance=False)
    for name, value in teacher.ema.module.state_dict().items():
        torch.testing.assert_close(student.denoiser.state_dict()[name], value, rtol=0, atol=0)
    assert "teacher" not in " ".join(student.state_dict())  # the teacher is not saved with the student
    calls = []
    denoiser = student.ema.module
    inner = denoiser.forward

    def counted(x_t, t, *args, **kwargs):
        calls.append((x_t.shape[0], kwargs.get("guidance")))
        return inner(x_t, t, *args, **kwargs)

    denoiser.forward = counted
    x_t, t, music, style = inputs(2, 12)
    Sampler(denoiser, student.diffusion, style_guidance=False).predict_x0(
        x_t, t, Condition(music, style), Guidance(2.5)
    )
    assert len(calls) == 1 and calls[0][0] == 2
    torch.testing.assert_close(calls[0][1], torch.full((2, 1), 2.5))


def test_distillation_run_learns_the_guided_teacher(tmp_path, tiny_synthetic):
    """train.py distill.teacher=...: the student's one pass moves from the teacher's conditional prediction towards
    its guided one (w = 2.5), on windows the student did not train on."""
    common = ("trainer.limit_val_batches=0", "model.dropout=0.0", "optimizer.lr=3e-3")
    _, taught = run(tmp_path / "teacher", tiny_synthetic, "trainer.max_steps=30", *common)
    cfg, result = run(
        tmp_path / "student", tiny_synthetic, "trainer.max_steps=100", "trainer.max_epochs=-1", "model.ema_decay=0.5",
        f"distill.teacher={taught['checkpoint']}", *common,
    )  # fmt: skip
    teacher, student = load_model(taught["checkpoint"]), load_model(result["checkpoint"])
    assert student.denoiser.guidance_inputs == 1 and teacher.denoiser.guidance_inputs == 0
    assert run_info(student.spec)["guidance_student"] and not run_info(teacher.spec)["guidance_student"]
    data = instantiate(cfg.data, audio_encoder=audio_encoder_from_config(cfg))
    data.setup("fit")
    batch = next(iter(data.val_dataloader()))  # the held-out windows
    x0, music = batch["motion"], batch["audio"]
    torch.manual_seed(5)
    t = torch.randint(0, 1000, (x0.shape[0],))
    x_t = teacher.diffusion.q_sample(x0, t, torch.randn_like(x0))
    style = teacher.style_for(batch["genre"], random=False)
    w = 2.5
    guided = Sampler(teacher.ema.module, teacher.diffusion, style_guidance=False, clip_x0=False).predict_x0(
        x_t, t, Condition(music, style), Guidance(w)
    )
    with torch.no_grad():
        before = teacher.ema.module(x_t, t, music, style)  # the untrained student
        after = student.ema.module(x_t, t, music, style, guidance=torch.full((x0.shape[0], 1), w))
    err_before, err_after = (before - guided).pow(2).mean(), (after - guided).pow(2).mean()
    assert err_after < 0.7 * err_before, (err_before, err_after)


def test_configuration_errors(tmp_path, tiny_synthetic):
    with pytest.raises(ConfigError, match="distill.max_weight must be a positive number"):
        DistillSettings.from_config({"teacher": "x", "max_weight": 0})
    with pytest.raises(ConfigError, match="unknown distill setting"):
        DistillSettings.from_config({"teacher": "x", "weights": 2})
    with pytest.raises(ConfigError, match="leave model.guidance_inputs at 0"):
        run(tmp_path / "a", tiny_synthetic, "model.guidance_inputs=1")
    _, taught = run(tmp_path / "teacher", tiny_synthetic, "trainer.max_steps=1", "trainer.limit_val_batches=0")
    ckpt = f"distill.teacher={taught['checkpoint']}"
    with pytest.raises(ConfigError, match=r"architecture differs from the teacher's in model\.d_model"):
        run(tmp_path / "b", tiny_synthetic, ckpt, "model.d_model=48", "model.n_heads=2")
    with pytest.raises(ConfigError, match="diffusion settings differ"):
        run(tmp_path / "c", tiny_synthetic, ckpt, "diffusion.num_steps=500")
    _, student = run(tmp_path / "d", tiny_synthetic, ckpt, "trainer.max_steps=1", "trainer.limit_val_batches=0")
    with pytest.raises(ConfigError, match="is itself a guidance-distilled student"):
        run(tmp_path / "e", tiny_synthetic, f"distill.teacher={student['checkpoint']}")


def test_generation_warns_above_the_students_trained_weights(tmp_path, caplog):
    from dgsdp.generation import DanceGenerator
    from dgsdp.sampling import GuidanceSettings, SamplingSettings

    teacher, student = _teacher_and_student(style_guidance=False)
    spec = dataclasses.replace(student.spec, record={"distill": {"teacher": "t.ckpt", "max_weight": 3.0}})
    generator = DanceGenerator(TrainedModel(spec), cache_dir=tmp_path)
    with caplog.at_level("WARNING"):
        generator.generate(12, music=torch.randn(12, 6), sampling=SamplingSettings(steps=2), seed=0)
    assert "extrapolates" not in caplog.text
    with caplog.at_level("WARNING"):
        generator.generate(
            12, music=torch.randn(12, 6), sampling=SamplingSettings(steps=2, guidance=GuidanceSettings(music=4.0))
        )
    assert "learnt guidance weights up to 3; 4 is beyond them" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):  # the teacher takes any weight
        DanceGenerator(teacher, cache_dir=tmp_path).generate(
            12, music=torch.randn(12, 6), sampling=SamplingSettings(steps=2, guidance=GuidanceSettings(music=4.0))
        )
    assert "extrapolates" not in caplog.text
