"""Dancing to a list of songs as generate.py does: the settings of a ``generate`` job as plain data
(:class:`GenerateSettings`, made from the config by the CLI), the model and how it dances to each song
(:class:`SongDancer`, shared with the real-song benchmark), and :func:`dance_songs`, which dances to every song and
writes its files, reporting the songs that failed while the others are still written."""

from __future__ import annotations

import dataclasses
import logging
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from dgsdp.audio.io import AUDIO_SUFFIXES
from dgsdp.editing import load_motion_file
from dgsdp.errors import ConfigError, DgsdpError
from dgsdp.generation.dance import Dance, write_motion
from dgsdp.generation.pipeline import DanceGenerator, EditSettings, Finishing, StylePlan, TextReadingChoice
from dgsdp.sampling import SamplingSettings

log = logging.getLogger(__name__)


def find_songs(music: str | os.PathLike | Sequence[str | os.PathLike] | None) -> list[Path]:
    """The audio files named by ``music``: a file, a folder (its audio files, sorted) or a list of either."""
    items = [] if music is None else [music] if isinstance(music, str | os.PathLike) else list(music)
    items = [item for item in items if str(item).strip()]
    if not items:
        raise ConfigError("give music=<audio file, folder or [list of files]> (wav, mp3, ogg or flac)")
    songs: list[Path] = []
    for item in items:
        p = Path(str(item)).expanduser()
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in AUDIO_SUFFIXES)
            if not found:
                raise ConfigError(f"music folder {p} has no audio files ({', '.join(AUDIO_SUFFIXES)})")
            songs += found
        else:
            songs.append(p)  # missing or undecodable files are reported per song
    if not songs:
        raise ConfigError("music= names no audio files")
    return songs


@dataclass
class GenerateSettings:
    """What a ``generate`` job asks for, checked: the model, the songs, the style, how to dance and what to write."""

    checkpoint: str
    music: list[str]
    style: str | None
    output_dir: Path
    cache_dir: str
    formats: list[str]
    sampling: SamplingSettings
    edit: EditSettings
    device: str = "cpu"
    max_song_seconds: float | None = None
    cleanup: bool = True
    beat_sync: bool = True
    finishing: Finishing = field(default_factory=Finishing)
    seconds: float | None = None
    blend_seconds: float = 2.0
    style_text: TextReadingChoice | None = None  # how free text is read; None: the checkpoint's choice
    num_samples: int = 1
    seed: int = 0
    progress: bool = False


def text_reading_arguments(choice: TextReadingChoice | None) -> dict[str, Any]:
    """:class:`DanceGenerator`'s text-reading arguments for a choice (none: the checkpoint's)."""
    if choice is None:
        return {}
    return {
        "text_reading": choice.how,
        "text_temperature": choice.temperature,
        "text_descriptions": choice.descriptions,
    }


@dataclass
class GenerationReport:
    """Files written per song and the error message of every song that failed."""

    written: dict[str, list[Path]] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.errors


@dataclass
class SongDancer:
    """The model of a ``generate`` job and how it dances to each song. generate.py and the real-song benchmark both
    dance through :meth:`dance`, so the benchmark measures exactly the default command."""

    generator: DanceGenerator
    settings: GenerateSettings

    @classmethod
    def from_settings(cls, settings: GenerateSettings) -> SongDancer:
        generator = DanceGenerator.from_checkpoint(
            settings.checkpoint, cache_dir=settings.cache_dir, device=settings.device,
            max_song_seconds=settings.max_song_seconds, **text_reading_arguments(settings.style_text),
        )  # fmt: skip
        edit = settings.edit
        if edit.motion is None and edit.motion_file:  # read once, before any song (one clear error for a bad file)
            motion = load_motion_file(edit.motion_file, fps=generator.fps, skeleton=generator.skeleton)
            edit = dataclasses.replace(edit, motion=motion)
        return cls(generator, dataclasses.replace(settings, edit=edit))

    @property
    def sampling(self) -> SamplingSettings:
        return self.settings.sampling

    def dance(self, song: Path, plan: StylePlan) -> Dance:
        """The dances (motions (num_samples, T, D), and the model's raw output) for one song in a resolved style."""
        s = self.settings
        return self.generator.dance_to_song(
            song, plan, edit=s.edit, seconds=s.seconds, blend_seconds=s.blend_seconds, num_samples=s.num_samples,
            sampling=s.sampling, seed=s.seed, progress=s.progress,
            cleanup=s.cleanup and s.finishing.floor(), beat_sync=s.beat_sync and s.finishing.beat_sync(),
        )  # fmt: skip


def _safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "song"


def dance_songs(settings: GenerateSettings) -> GenerationReport:
    """Dance to every song of ``settings.music`` and write the files; a song that fails (undecodable, too long,
    keyframes outside it, ...) is reported while the other songs are still written."""
    songs = find_songs(settings.music)
    dancer = SongDancer.from_settings(settings)
    generator = dancer.generator
    plan = generator.resolve_style(settings.style)
    report = GenerationReport()
    used: set[str] = set()
    bar = tqdm(songs, desc="songs", unit="song", disable=not settings.progress)
    for song in bar:
        bar.set_postfix_str(song.name)
        stem = _safe_name(song.stem)
        while stem in used:
            stem += "_"
        used.add(stem)
        try:
            dance = dancer.dance(song, plan)
            motions = dance.motion
            for note in dance.notes():  # half or double time, beat sync's choice
                log.info("%s: %s", song.name, note)
            files: list[Path] = []
            for k, motion in enumerate(motions):
                name = stem if settings.num_samples == 1 else f"{stem}_sample{k}"
                title = f"{song.stem} | {plan.text}" if plan.text else song.stem
                files += write_motion(
                    motion, settings.output_dir / name, fps=generator.fps, audio_path=song, formats=settings.formats,
                    title=title, floor_height=generator.floor_height, skeleton=generator.skeleton,
                )  # fmt: skip
            report.written[str(song)] = files
        except DgsdpError as e:
            log.error("%s: %s", song, e)
            report.errors[str(song)] = str(e)
    return report
