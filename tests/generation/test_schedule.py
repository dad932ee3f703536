"""Style schedules: parsing, blend weights against hand-worked cases, and style resolution errors."""

import pytest
import torch
from gen_helpers import STYLE_DIM

from dgsdp.errors import ConfigError
from dgsdp.generation import (
    DanceGenerator,
    StyleSpan,
    is_schedule,
    parse_schedule,
    schedule_styles,
    span_weights,
)


def test_parse_quoted_unquoted_and_open_end():
    spans = parse_schedule('0-30: krump; 30-60: slow graceful ballet jazz ;60 - end : "house; with a twist"')
    assert spans == [
        StyleSpan(0, 30, "krump"),
        StyleSpan(30, 60, "slow graceful ballet jazz"),
        StyleSpan(60, float("inf"), "house; with a twist"),
    ]
    assert parse_schedule("10.5s-20s: 'pop';  0-10.5: BR;") == [
        StyleSpan(0, 10.5, "BR"),
        StyleSpan(10.5, 20, "pop"),
    ]
    assert is_schedule("0-30: krump") and not is_schedule("krump") and not is_schedule("LA-style Hip-hop")


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("0-30 krump", "expected '<start>-<end>: <style>'"),
        ("30-10: krump", "ends before it starts"),
        ("0-30: krump; 20-40: pop", "overlap"),
        ("0-30: ; 30-40: pop", "has no style"),
        ('0-30: "krump', "unclosed quote"),
        ('0-30: "krump" pop', "expected ';'"),
        ("0-30: krump; hello", "expected '<start>-<end>: <style>'"),
    ],
)
def test_malformed_schedules(text, why):
    with pytest.raises(ConfigError, match="malformed style schedule") as err:
        parse_schedule(text)
    assert why in str(err.value) and "Expected e.g." in str(err.value)


def test_blend_weights_by_hand():
    # 1 FPS, spans [0, 10) and [10, 20), 2 s blend centred on 10 s: frame 9 -> 0, 10 -> 0.5, 11 -> 1
    w = span_weights([StyleSpan(0, 10, "a"), StyleSpan(10, 20, "b")], 25, fps=1, blend_seconds=2)
    assert w.shape == (25, 2)
    torch.testing.assert_close(w.sum(1), torch.ones(25))
    assert w[:10, 1].tolist() == [0.0] * 10
    assert w[9:12, 1].tolist() == [0.0, 0.5, 1.0]
    assert w[11:, 1].eq(1).all()  # after the last span: the last span's style
    # a gap 10..20 is split at 15 (nearest span); no blend: a hard switch at 15 s; before 5 s: the first span
    w = span_weights([StyleSpan(5, 10, "a"), StyleSpan(20, 30, "b")], 40, fps=1, blend_seconds=0)
    assert w[:15, 0].eq(1).all() and w[15:, 1].eq(1).all()


def test_schedule_styles_interpolate_the_embeddings():
    table = {"a": torch.tensor([1.0, 0.0]), "b": torch.tensor([0.0, 2.0]), "c": torch.tensor([4.0, 4.0])}
    spans = parse_schedule("0-2: a; 2-4: b; 4-6: c")
    styles = schedule_styles(spans, 180, table.__getitem__, fps=30, blend_seconds=1.0)
    assert styles.shape == (180, 2)
    torch.testing.assert_close(styles[0], table["a"])
    torch.testing.assert_close(styles[60], 0.5 * (table["a"] + table["b"]))  # 2 s: the middle of the blend
    torch.testing.assert_close(styles[90], table["b"])
    torch.testing.assert_close(styles[135], 0.5 * (table["b"] + table["c"]) + 0.5 * (table["c"] - table["b"]))
    torch.testing.assert_close(styles[179], table["c"])


def test_style_resolution_with_a_one_hot_model(tiny_model, tmp_path):
    gen = DanceGenerator(tiny_model, cache_dir=tmp_path)
    assert torch.equal(gen.resolve_style("krump").vector, torch.eye(STYLE_DIM)[7])
    assert torch.equal(gen.resolve_style("gKR").vector, torch.eye(STYLE_DIM)[7])
    plan = gen.resolve_style("0-1: krump; 1-2: ballet jazz")
    frames = gen.style_frames(plan, 60, blend_seconds=0.0)
    assert torch.equal(frames[:30], torch.eye(STYLE_DIM)[7].expand(30, -1))
    assert torch.equal(frames[30:], torch.eye(STYLE_DIM)[9].expand(30, -1))
    with pytest.raises(ConfigError, match="one-hot.*Known genres: BR"):
        gen.resolve_style("slow graceful moonwalk")
    with pytest.raises(ConfigError, match="one-hot"):
        gen.resolve_style("0-30: krump; 30-60: moonwalk")
    with pytest.raises(ConfigError, match="conditioned on style"):
        gen.resolve_style(None)
