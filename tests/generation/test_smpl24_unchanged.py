"""Skeletons as data left the SMPL-24 path as it was: a checkpoint written by the code before the skeleton
generalisation (commit b3e039a: the tiny one-hot model of ``gen_helpers.train_tiny_checkpoint``), with its song
and seed, gives the dance that code gave, raw and finished (beat sync and floor cleanup), sampled as that code
sampled (the windows not turned to agree, ``sampling.align_facing``, which came later).

The fixture was written by the code before; on the machine that wrote it the current code gives the same tensors
bit for bit. The test allows 1e-5 (metres and 6D units) so that another CPU's vector instructions, which round a
few sums differently, do not fail it."""

from pathlib import Path

import numpy as np

from dgsdp.generation.beatsync import BeatSync
from dgsdp.generation.pipeline import DanceGenerator
from dgsdp.motion import SMPL24
from dgsdp.sampling import SamplingSettings

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "smpl24_before_skeletons"


def test_an_old_checkpoint_gives_the_same_dance(tmp_path):
    generator = DanceGenerator.from_checkpoint(FIXTURE / "tiny.ckpt", cache_dir=tmp_path)
    assert generator.skeleton == SMPL24  # a checkpoint without a skeleton is an SMPL-24 run
    # the finishing as that code ran it: beat sync without its judge (docs/beatsync.md), which came later
    before = SamplingSettings(align_facing=False)
    dance = generator.dance_to_song(
        FIXTURE / "song.wav", "BR", seed=3, num_samples=2, beat_sync=BeatSync(judge=False), sampling=before
    )
    expected = np.load(FIXTURE / "dance.npz")
    assert dance.motion.shape == (2, 180, 151)
    np.testing.assert_allclose(dance.raw.numpy(), expected["raw"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(dance.motion.numpy(), expected["motion"], rtol=0, atol=1e-5)
    assert not np.allclose(expected["raw"], expected["motion"], atol=1e-3)  # the finishing did something to check
    # with the judge (the default), a dance whose retime it kept is the same; the others keep the model's timing
    judged = generator.dance_to_song(FIXTURE / "song.wav", "BR", seed=3, num_samples=2, sampling=before)
    kept = [bool(n["retimed"]) for n in judged.finishing]
    for k in range(2):
        if kept[k]:
            np.testing.assert_allclose(judged.motion[k].numpy(), expected["motion"][k], rtol=0, atol=1e-5)
        else:
            assert judged.finishing[k]["mean_shift_ms"] == 0.0
