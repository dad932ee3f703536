"""Tempo encoded in AIST++ music ids (e.g. ``mBR0`` is 80 BPM, ``mHO3`` is 125 BPM)."""

from __future__ import annotations

import re

GENRE_CODES = ("BR", "PO", "LO", "MH", "LH", "HO", "WA", "KR", "JS", "JB")

# The id as a whole name or as one "_"-separated part of a longer name (e.g. gBR_sBM_cAll_d04_mBR0_ch01).
_MUSIC_ID = re.compile(r"(?:^|[_/\\])m(" + "|".join(GENRE_CODES) + r")(\d)(?=$|[_.])")


def tempo_from_music_id(music_id: str | None) -> float | None:
    """BPM of an AIST++ song from its music id, or None when the name holds no AIST++ music id.

    For every genre but House, ``m<G><d>`` is ``80 + 10 * d`` BPM; for House (``mHO<d>``) it is
    ``110 + 5 * d`` BPM. Accepts a bare id (``"mBR0"``), a file name (``"mBR0.wav"``) or a sequence name.
    """
    if not music_id:
        return None
    match = _MUSIC_ID.search(str(music_id))
    if match is None:
        return None
    genre, digit = match.group(1), int(match.group(2))
    if genre == "HO":
        return 110.0 + 5.0 * digit
    return 80.0 + 10.0 * digit
