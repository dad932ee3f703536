"""Datasets: the AIST++ and FineDance readers, the synthetic generators, and the training/evaluation windows."""

from dgsdp.data.aistpp import (
    SequenceName,
    load_motion_pkl,
    music_path,
    music_tempo_bpm,
    parse_name,
    process_motion,
    read_split,
)

__all__ = [
    "SequenceName",
    "load_motion_pkl",
    "music_path",
    "music_tempo_bpm",
    "parse_name",
    "process_motion",
    "read_split",
]
