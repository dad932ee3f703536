"""Style schedules: a different style for each span of a song, with smooth transitions.

Syntax (times in seconds; ``end`` is the end of the song; the text may be quoted)::

    0-30: krump; 30-60: "slow graceful ballet jazz"; 60-end: house

Each span's style is a genre (code or name) or a free-text description. Frames are assigned to the span that
contains them; frames outside every span take the nearest span's style (a gap is split at its middle). Across
each boundary between neighbouring spans the style vector moves linearly from one span's vector to the next over
``blend_seconds`` centred on the boundary.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass

import torch

from dgsdp.errors import ConfigError

SCHEDULE_EXAMPLE = '0-30: krump; 30-60: "slow graceful ballet jazz"; 60-end: house'
_NUMBER = r"\d+(?:\.\d*)?|\.\d+"
_SPAN_HEAD = re.compile(rf"\s*(?P<start>{_NUMBER})\s*s?\s*-\s*(?P<end>{_NUMBER}|end)\s*s?\s*:\s*", re.IGNORECASE)
# A time span at the start marks a schedule, colon or not: "0-30 krump" is a schedule missing its colon (an error),
# not a description. Free text that starts with a time span on purpose takes the "text:" prefix.
_LOOKS_LIKE_SCHEDULE = re.compile(rf"^\s*(?:{_NUMBER})\s*s?\s*-\s*(?:{_NUMBER}|end)\s*s?(?:\b|:|$)", re.IGNORECASE)
_SPAN_WITHOUT_COLON = re.compile(
    rf"\s*(?P<span>(?:{_NUMBER})\s*s?\s*-\s*(?:{_NUMBER}|end)\s*s?)(?!\s*:)", re.IGNORECASE
)


@dataclass(frozen=True)
class StyleSpan:
    """One span of a schedule: seconds ``[start_s, end_s)`` (``end_s`` may be ``inf``) and its style text."""

    start_s: float
    end_s: float
    style: str


def is_schedule(text: str) -> bool:
    """Whether a style string is a schedule (starts with a time span ``<start>-<end>``) rather than one style."""
    return bool(_LOOKS_LIKE_SCHEDULE.match(text or ""))


def _error(text: str, why: str) -> ConfigError:
    return ConfigError(f"malformed style schedule {text!r}: {why}. Expected e.g. {SCHEDULE_EXAMPLE!r}")


def parse_schedule(text: str) -> list[StyleSpan]:
    """Parse a schedule into spans sorted by start; one ConfigError for anything malformed or overlapping."""
    spans: list[StyleSpan] = []
    pos, n = 0, len(text)
    while pos < n:
        if not text[pos:].strip():
            break
        head = _SPAN_HEAD.match(text, pos)
        if head is None:
            entry = text[pos:].split(";", 1)[0].strip()
            missing = _SPAN_WITHOUT_COLON.match(text, pos)
            if missing is not None:
                raise _error(
                    text,
                    f"expected '<start>-<end>: <style>', but entry {entry!r} has no ':' after the time span {missing['span'].strip()!r}",
                )
            raise _error(text, f"expected '<start>-<end>: <style>' at {text[pos:].strip()!r}")
        pos = head.end()
        if pos < n and text[pos] in "\"'":
            quote = text[pos]
            close = text.find(quote, pos + 1)
            if close < 0:
                raise _error(text, f"unclosed quote in {text[pos:]!r}")
            style = text[pos + 1 : close]
            pos = close + 1
            rest = re.match(r"\s*(;|$)", text[pos:])
            if rest is None:
                raise _error(text, f"expected ';' after the quoted style {style!r}")
            pos += rest.end()
        else:
            semi = text.find(";", pos)
            semi = n if semi < 0 else semi
            style = text[pos:semi]
            pos = semi + 1
        style = " ".join(style.split())
        start = float(head["start"])
        end = math.inf if head["end"].lower() == "end" else float(head["end"])
        if not style:
            raise _error(text, f"span {head['start']}-{head['end']} has no style")
        if not end > start:
            raise _error(text, f"span {head['start']}-{head['end']} ends before it starts")
        spans.append(StyleSpan(start, end, style))
    if not spans:
        raise _error(text, "no spans")
    spans.sort(key=lambda s: s.start_s)
    for a, b in zip(spans, spans[1:]):
        if b.start_s < a.end_s:
            raise _error(text, f"spans {a.start_s:g}-{a.end_s:g} and {b.start_s:g}-{b.end_s:g} overlap")
    return spans


def span_weights(spans: list[StyleSpan], n_frames: int, fps: float, blend_seconds: float) -> torch.Tensor:
    """Blend weights (n_frames, n_spans), rows summing to 1: how much of each span's style every frame takes.

    Frame f sits at time f / fps. Boundaries lie at the end of a span, or at the middle of a gap between spans;
    across each, the weight moves linearly from one span to the next over ``blend_seconds``.
    """
    times = torch.arange(n_frames, dtype=torch.float64) / fps
    k = len(spans)
    # progress[f] = sum of the ramps of the boundaries before frame f: 0 in span 0, 1 in span 1, ...
    progress = torch.zeros(n_frames, dtype=torch.float64)
    for a, b in zip(spans, spans[1:]):
        boundary = 0.5 * (a.end_s + b.start_s)
        if blend_seconds > 0:
            ramp = ((times - (boundary - blend_seconds / 2)) / blend_seconds).clamp(0, 1)
        else:
            ramp = (times >= boundary).double()
        progress += ramp
    # Piecewise-linear interpolation between consecutive spans at fractional position `progress`.
    weights = torch.zeros(n_frames, k, dtype=torch.float64)
    low = progress.floor().long().clamp(max=k - 1)
    frac = progress - low
    weights[torch.arange(n_frames), low] = 1 - frac
    high = (low + 1).clamp(max=k - 1)
    weights[torch.arange(n_frames), high] += frac
    return weights.float()


def schedule_styles(
    spans: list[StyleSpan],
    n_frames: int,
    embed: Callable[[str], torch.Tensor],
    *,
    fps: float = 30,
    blend_seconds: float = 2.0,
) -> torch.Tensor:
    """Per-frame style vectors (n_frames, ds) of a parsed schedule; ``embed(style_text) -> (ds,)``."""
    vectors = torch.stack([embed(s.style).float().cpu() for s in spans])  # (K, ds)
    return span_weights(spans, n_frames, fps, blend_seconds) @ vectors
