"""model.movement_channels: each training window's speed, level, arms, travel and turning, measured by hand here,
travel as more style channels (speed_conditioning=true is the same as listing speed); a run records its genres'
values; generation asks a genre for its medians, free text for what its words ask, and reports it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_train import run

from dgsdp.data.datamodule import Sequence, WindowDataset, add_movement, movement_statistics
from dgsdp.errors import ConfigError
from dgsdp.metrics.speed import SPEED_QUANTILES
from dgsdp.motion import SMPL24, MinMaxNormalizer, axis_angle_to_matrix, pack_pose, root_rotation_y_up_to_z_up
from dgsdp.style.movement import MOVEMENT_CHANNELS, movement_channels

ALL = "[speed,level,arms,travel,turning]"
STANDING_M = 0.95635239  # SMPL's rest pose: the pelvis above its lowest foot joint (the right toe), from the offsets


def test_the_channels_a_config_asks_for():
    assert movement_channels([], speed_conditioning=True) == ("speed",)
    assert movement_channels(["turning", "level"]) == ("level", "turning")  # always in MOVEMENT_CHANNELS' order
    assert movement_channels(["level", "speed"], speed_conditioning=True) == ("speed", "level")
    assert movement_channels(None) == ()
    for bad, message in ((["height"], "unknown channel"), (["arms", "arms"], "more than once"), ("speed", "a list")):
        with pytest.raises(ConfigError, match=message):
            movement_channels(bad)


def turning_glide(n: int, step_m: float, omega: float, height_m: float = 0.9) -> np.ndarray:
    """The rest pose standing (its pelvis ``height_m`` up), gliding ``step_m`` a frame along x and turning about the
    vertical at ``omega`` rad/s (30 FPS); pose vectors (n, 151)."""
    frames = torch.arange(n, dtype=torch.float64)
    trans = torch.stack([frames * step_m, torch.zeros(n, dtype=torch.float64),
                         torch.full((n,), height_m, dtype=torch.float64)], -1)  # fmt: skip
    rotations = torch.eye(3, dtype=torch.float64).repeat(n, 24, 1, 1)
    yaw = axis_angle_to_matrix(torch.stack([torch.zeros(n), torch.zeros(n), omega * frames / 30], -1).double())
    rotations[:, 0] = yaw @ root_rotation_y_up_to_z_up(rotations[:, 0])
    return pack_pose(torch.ones(n, 4, dtype=torch.float64), trans, rotations).float().numpy()


def test_window_values_and_their_statistics_by_hand():
    seqs = [Sequence("a", "BR", 0, "mBR0", turning_glide(60, 0.01, 2.0), None),
            Sequence("b", "PO", 1, "mPO0", turning_glide(60, 0.02, 0.5, height_m=0.7), None)]  # fmt: skip
    floor = 0.9 - STANDING_M  # where the lowest foot joint of the standing body is
    add_movement(seqs, SMPL24, 30, MOVEMENT_CHANNELS, floor)
    a, b = seqs[0].movement, seqs[1].movement
    assert list(a) == list(MOVEMENT_CHANNELS) and len(a["travel"]) == 59 and len(a["level"]) == 60
    np.testing.assert_allclose(a["travel"], 0.3, atol=1e-5)  # 1 cm a frame at 30 FPS
    np.testing.assert_allclose(a["turning"], 2.0, atol=1e-4)
    np.testing.assert_allclose(b["turning"], 0.5, atol=1e-4)
    np.testing.assert_allclose(a["level"], 1.0, atol=1e-5)
    np.testing.assert_allclose(b["level"], (0.7 - floor) / STANDING_M, atol=1e-5)
    # arms out to the side (the rest pose): the wrists a little below the shoulders, in arm lengths
    left = (-0.01564902 + 0.01269811) / (math.hypot(0.2553319, 0.01564902, 0.02294649)
                                          + math.hypot(0.26570925, 0.01269811, 0.00737473))  # fmt: skip
    right = (-0.01436928 + 0.00679372) / (math.hypot(0.26012748, 0.01436928, 0.03126873)
                                           + math.hypot(0.26910836, 0.00679372, 0.00602676))  # fmt: skip
    np.testing.assert_allclose(a["arms"], (left + right) / 2, atol=1e-5)
    normalizer = MinMaxNormalizer(151)
    normalizer.fit(torch.from_numpy(np.concatenate([s.motion for s in seqs])))
    ds = WindowDataset(seqs, normalizer, length=30, stride=15)
    item = ds[0]
    assert item["movement"].shape == (5,)
    np.testing.assert_allclose(ds.window_movement(seqs[0], 0, rate=1.5), [
        float(np.mean(a["speed"][:44])) * 1.5, 1.0, (left + right) / 2, 0.45, 3.0], atol=1e-4)  # fmt: skip
    quantiles, median, spread = movement_statistics(ds, n_genres=3)
    assert quantiles.shape == (5, 3, SPEED_QUANTILES) and np.isnan(quantiles[:, 2]).all()
    values = np.asarray([ds.window_movement(seqs[i], s) for i, s in ds.index])
    np.testing.assert_allclose(median, np.median(values, axis=0), rtol=1e-6)
    np.testing.assert_allclose(spread, np.quantile(values, 0.9, axis=0) - np.quantile(values, 0.1, axis=0), atol=1e-9)
    np.testing.assert_allclose(quantiles[3, 1], 0.6, atol=1e-4)  # b travels 2 cm a frame in every window


# a few words of each attribute's ends (the shipped reader composes many more: fitting it on MiniLM takes minutes)
FEW_WORDS = {
    "slow": ["calm", "lazy"], "fast": ["frantic", "rapid"], "templates": ["{word} {genre}"],
    "neutral_templates": ["{genre}", "a {genre} dance"], "movement_templates": ["{genre}, {word}"],
    "movement": {
        "level": {"lower": ["crouched low", "down low to the ground"], "higher": ["standing tall", "upright"]},
        "arms": {"lower": ["arms down", "arms by the sides"], "higher": ["arms raised overhead", "arms up high"]},
        "travel": {"lower": ["on the spot", "in one place"], "higher": ["travelling across the floor", "covering ground"]},
        "turning": {"lower": ["facing ahead", "facing forward"], "higher": ["spinning", "turning around"]},
    },
}  # fmt: skip


def test_words_ask_an_attribute_beyond_a_genre_that_hardly_varies():
    from dgsdp.style.movement import ATTRIBUTE_REACH
    from dgsdp.style.reading import SPEED_SPAN
    from dgsdp.trained import RunSpec
    from dgsdp.training import DanceDiffusion

    spec = RunSpec.from_groups(style_dim=4, style_bank_size=4, n_genres=2, d_model=16, n_layers=1, n_heads=2,
                               ff_dim=32, movement_channels=["speed", "turning"])  # fmt: skip
    model = DanceDiffusion(spec)
    steps = torch.linspace(0, 1, SPEED_QUANTILES)
    speed = torch.stack([0.2 + 0.4 * steps, 0.5 + 1.0 * steps])  # genre 0: 0.2..0.6 m/s, genre 1: 0.5..1.5
    turning = torch.stack([0.001 + 0.009 * steps, 0.1 + 2.9 * steps])  # genre 0 hardly turns, genre 1 up to 3 rad/s
    model.set_movement_statistics(torch.stack([speed, turning]), [0.5, 0.02], [1.0, 0.8])
    both = torch.tensor([0, 1])
    # nothing asked: each genre's medians
    torch.testing.assert_close(model.asked_movement(both, torch.zeros(2)), model.genre_movement(both))
    # speed: the genre's own quantile; turning for genre 1: its own quantile, farther than the reach
    at = 0.5 + SPEED_SPAN
    full = model.asked_movement(both, torch.tensor([1.0, 1.0]))
    torch.testing.assert_close(full[:, 0], torch.tensor([0.2 + 0.4 * at, 0.5 + 1.0 * at]))
    assert float(full[1, 1]) == pytest.approx(0.1 + 2.9 * at)
    # turning for genre 0: its 90th percentile (0.0091) asks no turn; the word asks the reach of all windows' spread
    median0 = 0.001 + 0.009 * 0.5
    assert float(full[0, 1]) == pytest.approx(median0 + ATTRIBUTE_REACH * 0.8)
    half = model.asked_movement(both, torch.tensor([0.0, 0.5]))
    assert float(half[0, 1]) == pytest.approx(median0 + 0.5 * ATTRIBUTE_REACH * 0.8)
    # less turning: never below the lowest value of any genre's windows
    assert float(model.asked_movement(both, torch.tensor([0.0, -1.0]))[0, 1]) == pytest.approx(0.001)


def test_a_run_records_its_movement_and_generation_asks_for_it(tmp_path, tiny_synthetic):
    from dgsdp.generation import DanceGenerator
    from dgsdp.style.embeddings import load_prompts
    from dgsdp.style.reading import TextRouter
    from dgsdp.trained import load_model

    _, result = run(tmp_path, tiny_synthetic, "style=prompt", f"model.movement_channels={ALL}",
                    "generation.style_text_reading=router", "trainer.max_steps=2", "trainer.limit_val_batches=0")  # fmt: skip
    model = load_model(result["checkpoint"])
    assert model.movement_channels == MOVEMENT_CHANNELS and model.speed_conditioning
    ds = model.style_dim
    assert model.denoiser.style_in == ds + 5 and model.denoiser.null_style.shape == (ds + 5,)
    for name in MOVEMENT_CHANNELS:
        table = model.quantile_table(name)
        assert table.shape == (10, SPEED_QUANTILES) and torch.isfinite(table).all(), name
        assert (table[:, 1:] >= table[:, :-1]).all(), name
        assert math.isfinite(float(getattr(model, f"{name}_reference")))
    assert not hasattr(model, "speed_spread") and float(model.level_spread) > 0
    # the encoding: speed as log2 of its ratio to the median, the others in spreads from their medians
    medians = torch.stack([getattr(model, f"{n}_reference") for n in MOVEMENT_CHANNELS])
    values = medians.clone()
    values[0] *= 2
    values[1] += 0.5 * model.level_spread
    values[4] -= model.turning_spread
    np.testing.assert_allclose(model.movement_encoding(values[None])[0].numpy(), [1, 0.5, 0, 0, -1], atol=1e-5)
    # a genre asked by name: its medians
    gen = DanceGenerator(model, cache_dir=tiny_synthetic["cache"])
    kr = gen.embedder().vocab.index("krump")
    vector, reading = gen.read_style("krump")
    medians_kr = model.genre_movement(torch.tensor([kr]))[0]
    np.testing.assert_allclose(medians_kr.numpy(), [float(model.quantile_table(n)[kr, 5]) for n in MOVEMENT_CHANNELS])
    assert vector.shape == (ds + 5,) and torch.allclose(vector[ds:], model.movement_encoding(medians_kr), atol=1e-5)
    assert reading.speed_m_s == pytest.approx(float(medians_kr[0]))
    assert dict(reading.movement) == pytest.approx(dict(zip(MOVEMENT_CHANNELS[1:], medians_kr[1:].tolist())))
    # free text: the router reads its movement words and asks for those quantiles of the genre read
    embedder = gen.embedder()
    per_genre = load_prompts(embedder.prompts_file, embedder.vocab)
    names = [n.lower() for n in embedder.vocab.names]
    gen._router = TextRouter(per_genre, embedder.embed_texts, names, FEW_WORDS)  # the run's reader, fewer words
    text = f"{per_genre[kr][0].rstrip('.')}, crouched low with arms raised overhead"  # a krump description + words
    vector, reading = gen.read_style(text)
    assert reading.known and reading.genre is not None
    scores = dict(reading.attributes)
    assert set(scores) == {"level", "arms", "travel", "turning"}
    assert scores == pytest.approx(gen.router().read_attributes(text))
    router = gen.router()  # the few words still tell the ends apart around a genre
    assert router.read_attributes("krump, crouched low")["level"] < router.read_attributes("krump, upright")["level"]
    g = gen.embedder().vocab.index(reading.genre)
    asked = model.asked_movement(
        torch.tensor([g]), torch.tensor([reading.energy, *(scores[n] for n in MOVEMENT_CHANNELS[1:])])
    )[0]
    assert torch.allclose(vector[ds:], model.movement_encoding(asked), atol=1e-5)
    assert dict(reading.movement)["level"] == pytest.approx(float(asked[1]))
    assert reading.describe().endswith("; " + reading.describe_attributes())
    assert [part.split()[0] for part in reading.describe_attributes().split(", ")] == list(MOVEMENT_CHANNELS[1:])
    styles = model.style_for(torch.tensor([kr, 0]), random=False)  # evaluation and callbacks: the genres' medians
    assert styles.shape == (2, ds + 5) and torch.allclose(
        styles[0, ds:], model.movement_encoding(medians_kr), atol=1e-5
    )
