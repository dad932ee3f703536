"""Long-form continuity and style schedules on a small model trained here on the synthetic dataset (slow)."""

import numpy as np
import pytest
import torch
from gen_helpers import write_click_song
from hydra import compose, initialize_config_dir

from dgsdp.editing import load_motion_file
from dgsdp.generation import DanceGenerator, WindowLayout
from dgsdp.metrics import GenreClassifier, geometric_features, kinetic_features
from dgsdp.motion import pose_to_joints
from dgsdp.resources import CONFIG_DIR
from dgsdp.sampling import GuidanceSettings, SamplingSettings

pytestmark = pytest.mark.slow

GENRES = ("KR", "JB", "HO")
SPANS = {"KR": (0, 15), "JB": (15, 30), "HO": (30, 45)}
TRAIN_STEPS = 1500


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """(generator, dataset root): the small model trained for about 8 CPU minutes on 3 genres, with style dropout
    so that sampling can amplify the style (style guidance)."""
    synthetic = pytest.importorskip("dgsdp.data.synthetic")
    from dgsdp.cli.train import train

    tmp = tmp_path_factory.mktemp("trained")
    root = synthetic.generate_synthetic_aistpp(tmp / "synthetic", seed=0, sequences_per_genre=4, genres=GENRES)
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(
            "train",
            overrides=[
                "style=onehot", "logger=none", "~callbacks.progress", "run_name=slow", f"data.root={root}",
                "data.synthetic=null", f"paths.cache_dir={tmp / 'cache'}", f"paths.output_dir={tmp / 'run'}",
                "model=small", "model.dropout=0.0", "diffusion.style_drop_prob=0.2", f"trainer.max_steps={TRAIN_STEPS}", "trainer.max_epochs=10000",
                "trainer.accelerator=cpu", "+trainer.limit_val_batches=1", "trainer.check_val_every_n_epoch=50",
                "data.batch_size=32", "data.progress=false",
            ],
        )  # fmt: skip
    ckpt = train(cfg)["checkpoint"]
    return DanceGenerator.from_checkpoint(ckpt, cache_dir=tmp / "cache", device="cpu"), root, tmp


def frame_jumps(motion: torch.Tensor) -> np.ndarray:
    """Largest joint displacement (m) from each frame to the next: (T - 1,)."""
    joints = pose_to_joints(motion.double())
    return (joints[1:] - joints[:-1]).norm(dim=-1).amax(dim=-1).numpy()


def test_longform_95_s_song_is_continuous_at_window_boundaries(trained):
    generator, _, tmp = trained
    song = tmp / "song95.wav"
    write_click_song(song, 95.0, bpm=110)
    music, n = generator.music_features(song)
    assert n == 95 * 30
    motion = generator.generate(n, music=music, style=generator.resolve_style("krump").vector,
                                sampling=SamplingSettings(steps=20), seed=0)[0]  # fmt: skip
    assert motion.shape == (95 * 30, 151)
    layout = WindowLayout(n, 150, 75)
    edges = sorted({s for s in layout.starts()[1:]} | {s + 150 for s in layout.starts() if s + 150 < n})
    jumps = frame_jumps(motion)
    at_edges = np.isin(np.arange(n - 1), [e - 1 for e in edges])
    assert jumps[at_edges].max() <= jumps[~at_edges].max()


def dance_features(motion: torch.Tensor) -> np.ndarray:
    joints = pose_to_joints(motion.double()).numpy()
    return np.concatenate([
        kinetic_features(joints, fps=30, up_axis="z", mode="corrected"),
        geometric_features(joints, fps=30, up_axis="z", mode="corrected"),
    ])  # fmt: skip


def windows(motion: torch.Tensor, start: int, stop: int, length: int = 150, stride: int = 75):
    """Whole windows of ``length`` frames starting every ``stride`` frames within [start, min(stop, T))."""
    stop = min(stop, len(motion))
    return [motion[s : s + length] for s in range(start, stop - length + 1, stride)]


def test_style_schedule_spans_dance_their_genres(trained):
    generator, root, tmp = trained
    feats, labels = [], []
    for pkl in sorted((root / "motions").glob("*.pkl")):
        genre = pkl.name[1:3]
        for w in windows(load_motion_file(pkl), 0, 10**9):
            feats.append(dance_features(w))
            labels.append(genre)
    clf = GenreClassifier().fit(np.stack(feats), np.array(labels))

    song = tmp / "song45.wav"
    write_click_song(song, 45.0, bpm=110)
    music, n = generator.music_features(song)
    plan = generator.resolve_style("; ".join(f"{a}-{b}: {g}" for g, (a, b) in SPANS.items()))
    style = generator.style_frames(plan, n, blend_seconds=1.0)
    # music weight 1, style weight 2: x = x_m + 2 (x_ms - x_m) amplifies the style only (an undertrained model's
    # dances collapse towards the clamp when the music is extrapolated at w = 2)
    sampling = SamplingSettings(steps=50, guidance=GuidanceSettings(music=1.0, style=2.0))
    motions = generator.generate(n, music=music, style=style, num_samples=3, sampling=sampling, seed=0)
    predicted, wanted = [], []
    for motion in motions:
        for genre, (a, b) in SPANS.items():
            for w in windows(motion, int((a + 1) * 30), int((b - 1) * 30), stride=60):
                predicted.append(clf.predict(dance_features(w)[None])[0])
                wanted.append(genre)
    accuracy = float(np.mean(np.array(predicted) == np.array(wanted)))
    print(f"style schedule: {accuracy:.2f} of {len(wanted)} windows danced in their scheduled genre (chance 0.33)")
    assert accuracy >= 0.55, f"accuracy {accuracy:.2f} over {len(wanted)} windows (chance 0.33)"
