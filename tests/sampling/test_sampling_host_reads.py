"""Sampling reads nothing back from the device per step: every read of a tensor's value to the host (which makes the
host wait for a GPU) happens once per run, so a run with more steps makes exactly as many. Checked on the real
path (DanceGenerator.generate: long-form windows, guidance passes, the conditioning cached once per run) for the
default sampler, EDGE's procedure, an edit, a guidance-distilled student in chunks and a concatenated style; on a
GPU (``-m gpu``) by torch's own sync detection, which also sees copies from the host."""

from __future__ import annotations

import dataclasses
import warnings

import pytest
import torch
from generation.gen_helpers import random_motion
from generation.gen_helpers import tiny_model as build_tiny_model
from host_reads import count_host_reads, differences

from dgsdp.benchmarks.generation import student_of
from dgsdp.generation import DanceGenerator
from dgsdp.sampling import SamplingSettings
from dgsdp.style import StyleBank
from dgsdp.training import DanceDiffusion

FRAMES = 330  # four long-form windows


def concat_model() -> DanceDiffusion:
    """The tiny model with its style concatenated to the music (the rows sharing the null music are compared once
    per run, by their styles)."""
    base = build_tiny_model()
    spec = dataclasses.replace(base.spec, model={**base.spec.model, "style_injection": "concat"})
    torch.manual_seed(0)
    model = DanceDiffusion(spec).eval()
    model.set_style_bank(StyleBank(torch.eye(10), torch.arange(10), 10))
    model.normalizer.load_state_dict(base.normalizer.state_dict())
    return model


CASES = {  # the model, its sampling settings, whether the dance is an edit
    "default": ("tiny", {}, False),
    "edge": ("tiny", {"method": "ddim", "longform": "edge", "project_rotations": "none"}, False),
    "unipc, an edit": ("tiny", {"method": "unipc"}, True),
    "ddim, an edit": ("tiny", {"method": "ddim"}, True),
    "sde, a student in chunks": ("student", {"method": "dpmpp_2m_sde", "chunk_size": 3}, False),
    "concat": ("concat", {}, False),
}


def dance(generator: DanceGenerator, settings: SamplingSettings, edit: bool) -> torch.Tensor:
    music = torch.randn(FRAMES, 35, generator=torch.Generator().manual_seed(1))
    mask = known = None
    if edit:
        known = random_motion(FRAMES, seed=2)
        mask = torch.zeros(FRAMES, 151)
        mask[:60] = 1
    return generator.generate(FRAMES, music=music, style=torch.eye(10)[4], mask=mask, known=known, sampling=settings)


@pytest.fixture(scope="module")
def generators(tmp_path_factory) -> dict[str, DanceGenerator]:
    tiny = build_tiny_model()
    models = {"tiny": tiny, "student": student_of(tiny), "concat": concat_model()}
    cache = tmp_path_factory.mktemp("cache")
    return {name: DanceGenerator(model, cache_dir=cache) for name, model in models.items()}


@pytest.mark.parametrize("case", list(CASES))
def test_sampling_reads_back_nothing_per_step(generators, case):
    model, options, edit = CASES[case]
    runs = []
    # 3 and 6 steps: the guidance ramp never lands on weight 1 (a single pass, conditioned once more), and the
    # solvers space both in lambda
    for steps in (3, 6):
        with count_host_reads() as reads:
            dance(generators[model], SamplingSettings(steps=steps, **options), edit)
        runs.append(reads)
    assert runs[0].total > 0  # the counting works: a run reads its few values once (conditioning, the result)
    assert runs[1].calls == runs[0].calls, f"reads that grow with the steps: {differences(*runs)}"


@pytest.mark.gpu
@pytest.mark.parametrize("case", list(CASES))
def test_no_device_sync_per_sampling_step_on_cuda(tmp_path, case):
    """torch's sync detection counts every wait for the GPU, copies from the host included: as many with 6 steps
    as with 3."""
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    model, options, edit = CASES[case]
    tiny = build_tiny_model()
    built = {"tiny": tiny, "student": student_of(tiny), "concat": concat_model()}[model]
    generator = DanceGenerator(built, cache_dir=tmp_path, device="cuda")
    counts = []
    for steps in (3, 3, 6):  # the first run warms up (tables built once per device)
        settings = SamplingSettings(steps=steps, **options)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            torch.cuda.set_sync_debug_mode("warn")
            try:
                dance(generator, settings, edit)
            finally:
                torch.cuda.set_sync_debug_mode("default")
        counts.append([f"{w.filename}:{w.lineno}" for w in caught if "synchroniz" in str(w.message)])
    assert len(counts[2]) == len(counts[1]), f"syncs with 3 steps: {counts[1]}; with 6 steps: {counts[2]}"
