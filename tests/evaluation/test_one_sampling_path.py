"""Evaluation samples through the same path as generate.py: the same checkpoint, song, seed and settings give the
same motion from both."""

import numpy as np
import torch

from dgsdp.cli.config import compose_config
from dgsdp.cli.generate import generate
from dgsdp.data.aistpp import music_path
from dgsdp.evaluation import Evaluator, ProtocolSpec, Variant, clip_requests, clip_seed
from dgsdp.generation import DanceGenerator
from dgsdp.motion import clean_motion
from dgsdp.sampling import GuidanceSettings, SamplingSettings
from dgsdp.trained import load_model


def test_evaluate_and_generate_make_the_same_dance(trained_run, tmp_path):
    generator = DanceGenerator(load_model(trained_run["checkpoint"]), cache_dir=trained_run["cache"])
    spec = ProtocolSpec.from_config({"name": "t", "lengths_seconds": [5.0], "stride_seconds": 2.5})
    ev = Evaluator(generator, spec, data_root=trained_run["root"], cache_dir=trained_run["cache"], progress=False)
    clips = ev.source.clips(ev.source.load_split("test"), 5.0)
    starts = [c for c in clips if c.start == 0]  # generate.py dances from the start of the song
    chosen = [starts[1], starts[0], clips[1]]  # batched with others, in another order
    settings = SamplingSettings(steps=3, eta=1.0, guidance=GuidanceSettings(music=2.0))
    requests = clip_requests(generator, chosen, Variant(5.0, 2.0, "none", "w2"), spec, seed=7, trial=1)
    evaluated = generator.generate_many(requests, settings)[1][0]  # the dance for starts[0]

    clip = starts[0]
    song = music_path(trained_run["root"], clip.seq.music_id)
    genre = clip.seq.genre
    cfg = compose_config(
        "generate",
        [
            f"checkpoint={trained_run['checkpoint']}", f"music={song}", f"style={genre}", "seconds=5",
            f"seed={clip_seed(7, 1, clip.index)}", "sampling.steps=3", "sampling.eta=1.0", "sampling.guidance.music=2.0",
            "formats=[npy]", "progress=false", "device=cpu", f"output_dir={tmp_path}",
            f"paths.cache_dir={trained_run['cache']}",
        ],
    )  # fmt: skip
    report = generate(cfg)
    assert report.ok, report.errors
    generated = np.load(tmp_path / f"{song.stem}.npy")
    assert generated.shape == (150, 151)
    # generate.py finishes the dance by default (retimed onto the beats, feet on the floor); evaluation scores the
    # raw dance unless cleanup=true, and then finishes it the same way with the clip's beats
    assert len(clip.beats_30fps) >= 2
    finished = generator.finish(evaluated[None], clip.beats_30fps)[0]
    # (batched with other clips, the raw dances differ by float rounding, which the turn and tilt limits can grow)
    np.testing.assert_allclose(generated, finished.numpy(), rtol=0, atol=1e-4)
    floor_only = clean_motion(evaluated, generator.fps, generator.floor_height)
    assert torch.abs(finished - floor_only).max() > 1e-3  # the retiming moved something
    # and it is not a coincidence of the settings: another seed gives another dance
    other = generator.generate(150, music=requests[1].music, style=requests[1].style, seed=8, sampling=settings)
    assert torch.abs(other[0] - evaluated).max() > 1e-2
