"""Generation: long-form sampling of whole songs, style schedules, and the pipeline behind generate.py."""

from dgsdp.generation.dance import Dance, write_motion
from dgsdp.generation.longform import (
    ChunkedDenoiser,
    DanceRequest,
    WindowLayout,
    cut_windows,
    sample_items,
    sample_long,
    share_overlaps,
    stitch_windows,
)
from dgsdp.generation.pipeline import DanceGenerator, EditSettings, Finishing, StylePlan
from dgsdp.generation.schedule import StyleSpan, is_schedule, parse_schedule, schedule_styles, span_weights
from dgsdp.generation.songs import GenerateSettings, GenerationReport, SongDancer, dance_songs, find_songs
from dgsdp.sampling import SamplingSettings

__all__ = [
    "ChunkedDenoiser",
    "Dance",
    "DanceGenerator",
    "DanceRequest",
    "EditSettings",
    "Finishing",
    "GenerateSettings",
    "GenerationReport",
    "SamplingSettings",
    "SongDancer",
    "StylePlan",
    "StyleSpan",
    "WindowLayout",
    "cut_windows",
    "dance_songs",
    "find_songs",
    "is_schedule",
    "parse_schedule",
    "sample_items",
    "sample_long",
    "schedule_styles",
    "share_overlaps",
    "span_weights",
    "stitch_windows",
    "write_motion",
]
