"""The output formats of a generated motion, checked once before anything is generated."""

from __future__ import annotations

import difflib
from collections.abc import Iterable

from dgsdp.errors import ConfigError

MOTION_FORMATS: dict[str, str] = {
    "pkl": "AIST++ motion pickle (.pkl, y-up SMPL parameters)",
    "bvh": "BVH for Blender (.bvh)",
    "glb": "glTF binary with a skinned body, for Blender, Unity and game engines (.glb)",
    "video": "stick-figure video with the music (.mp4; a silent .gif without ffmpeg)",
    "npy": "raw pose vectors (.npy)",
}
"""Every format ``write_motion`` writes, with what it is."""


def check_formats(formats: str | Iterable[str] | None) -> list[str]:
    """The requested formats as a list in the order given, without repeats; ConfigError for an unknown or empty
    request, listing the valid formats (and the closest one to a misspelt name)."""
    if formats is None:
        requested: list[str] = []
    elif isinstance(formats, str):
        requested = [f for f in formats.replace(",", " ").split()]
    else:
        requested = [str(f) for f in formats]
    valid = ", ".join(f"{k} ({v})" for k, v in MOTION_FORMATS.items())
    if not requested:
        raise ConfigError(f"no output format requested: give formats=[...] with some of {valid}")
    out: list[str] = []
    for fmt in requested:
        key = fmt.strip().lower().lstrip(".")
        key = {"mp4": "video", "gif": "video"}.get(key, key)
        if key not in MOTION_FORMATS:
            close = difflib.get_close_matches(key, list(MOTION_FORMATS), n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"unknown output format {fmt!r}{hint or '.'} Valid formats: {valid}")
        if key not in out:
            out.append(key)
    return out
