"""Style conditioning: genre vocabulary, text encoders, style embeddings and their injection into the model."""

from dgsdp.style.embeddings import DEFAULT_PROMPTS_FILE, STYLE_KINDS, StyleBank, StyleEmbedder, load_prompts
from dgsdp.style.injection import StyleModulation, concat_style
from dgsdp.style.text_encoders import ClipTextEncoder, MiniLMTextEncoder, TextEncoder
from dgsdp.style.vocab import AISTPP_GENRES, GenreVocab

__all__ = [
    "AISTPP_GENRES",
    "DEFAULT_PROMPTS_FILE",
    "STYLE_KINDS",
    "ClipTextEncoder",
    "GenreVocab",
    "MiniLMTextEncoder",
    "StyleBank",
    "StyleEmbedder",
    "StyleModulation",
    "TextEncoder",
    "concat_style",
    "load_prompts",
]
