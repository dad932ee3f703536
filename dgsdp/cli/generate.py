"""``python generate.py``: dance to songs with a trained checkpoint, optionally editing a given motion.

Reads the checkpoint, the style and any given motion once (a problem with them stops the run with one clear
message), then generates every song; a song that fails (undecodable, too long, keyframes outside it, ...) is
reported at the end while the other songs are still written. The exit code is non-zero if anything failed.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig
from tqdm.auto import tqdm

from dgsdp.cli.config import GENERATE_CONFIG_NAME, as_list, generate_configs
from dgsdp.cli.runtime import run_main
from dgsdp.editing import check_task, load_motion_file
from dgsdp.errors import ConfigError, DgsdpError
from dgsdp.export import check_formats
from dgsdp.generation.pipeline import DanceGenerator, EditSettings, StylePlan, find_songs, write_motion
from dgsdp.sampling import SamplingSettings

log = logging.getLogger(__name__)


@dataclass
class GenerationReport:
    """Files written per song and the error message of every song that failed."""

    written: dict[str, list[Path]] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.errors


def edit_settings(cfg: DictConfig, fps: int) -> EditSettings:
    """The editing task with its given motion read from file (one clear error for a bad file)."""
    task = check_task(cfg.task)
    file = {"seed_motion": cfg.seed_motion_file, "inbetween": cfg.seed_motion_file}.get(task)
    if task == "keyframes":
        file = cfg.keyframes_file
    file = file or cfg.motion_file
    if task != "none" and not file:
        raise ConfigError(
            f"task={task} needs the given motion: set seed_motion_file (seed_motion, inbetween), "
            "keyframes_file (keyframes) or motion_file (any task); .npy (N, 151) or AIST++ .pkl"
        )
    motion = load_motion_file(file, fps=fps) if file else None
    return EditSettings(
        task=task,
        motion=motion,
        seed_frames=int(cfg.seed_frames),
        end_frames=int(cfg.end_frames),
        inpaint_fraction=float(cfg.inpaint_fraction),
        joints=as_list(cfg.joints),
        with_root=bool(cfg.with_root),
        keyframes=[int(k) for k in as_list(cfg.keyframes) or []] or None,
        keyframe_seconds=[float(s) for s in as_list(cfg.keyframe_seconds) or []] or None,
    )


def _safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "song"


@dataclass
class GenerateJob:
    """What a ``generate`` config asks for, checked: the model, and how to dance to each song. generate.py and the
    real-song benchmark both dance through :meth:`dance`, so the benchmark measures exactly the default command."""

    generator: DanceGenerator
    sampling: SamplingSettings
    edit: EditSettings
    cleanup: bool
    beat_sync: bool
    seconds: float | None
    blend_seconds: float
    num_samples: int
    seed: int
    progress: bool

    @classmethod
    def from_config(cls, cfg: DictConfig) -> GenerateJob:
        if not cfg.get("checkpoint"):
            raise ConfigError("give checkpoint=<path of a trained model's .ckpt file>")
        sampling = SamplingSettings.from_config(cfg.sampling)
        if cfg.seconds is not None and float(cfg.seconds) <= 0:
            raise ConfigError(f"seconds must be positive (the length of song to dance to), got {cfg.seconds}")
        cleanup = cfg.get("cleanup", True)
        if not isinstance(cleanup, bool):
            raise ConfigError(f"cleanup must be true or false (feet on the floor), got {cleanup!r}")
        beat_sync = cfg.get("beat_sync", True)
        if not isinstance(beat_sync, bool):
            raise ConfigError(f"beat_sync must be true or false (pauses retimed onto the beats), got {beat_sync!r}")
        num_samples = int(cfg.num_samples)
        if num_samples < 1:
            raise ConfigError(f"num_samples must be at least 1, got {num_samples}")
        generator = DanceGenerator.from_checkpoint(
            cfg.checkpoint,
            cache_dir=cfg.paths.cache_dir,
            device=str(cfg.device),
            max_song_seconds=None if cfg.max_song_seconds is None else float(cfg.max_song_seconds),
        )
        return cls(
            generator, sampling, edit_settings(cfg, generator.fps), cleanup, beat_sync,
            None if cfg.seconds is None else float(cfg.seconds), float(cfg.schedule_blend_seconds), num_samples,
            int(cfg.seed), bool(cfg.progress),
        )  # fmt: skip

    def dance(self, song: Path, plan: StylePlan) -> torch.Tensor:
        """The motions (num_samples, T, 151) for one song in a resolved style."""
        return self.generator.dance_to_song(
            song, plan, edit=self.edit, seconds=self.seconds, blend_seconds=self.blend_seconds,
            num_samples=self.num_samples, sampling=self.sampling, seed=self.seed, progress=self.progress,
            cleanup=self.cleanup, beat_sync=self.beat_sync,
        ).motion  # fmt: skip


def generate(cfg: DictConfig) -> GenerationReport:
    """Run one generation job from a composed ``generate`` config; returns what was written and what failed."""
    if not cfg.get("checkpoint"):
        raise ConfigError("give checkpoint=<path of a trained model's .ckpt file>")
    songs = find_songs(as_list(cfg.music) if not isinstance(cfg.music, str) else cfg.music)
    formats = check_formats([str(f) for f in as_list(cfg.formats) or []])
    job = GenerateJob.from_config(cfg)
    generator = job.generator
    plan = generator.resolve_style(cfg.style)
    out_dir = Path(cfg.output_dir).expanduser()
    report = GenerationReport()
    used: set[str] = set()
    bar = tqdm(songs, desc="songs", unit="song", disable=not cfg.progress)
    for song in bar:
        bar.set_postfix_str(song.name)
        stem = _safe_name(song.stem)
        while stem in used:
            stem += "_"
        used.add(stem)
        try:
            motions = job.dance(song, plan)
            files: list[Path] = []
            for k, motion in enumerate(motions):
                name = stem if job.num_samples == 1 else f"{stem}_sample{k}"
                title = f"{song.stem} | {plan.text}" if plan.text else song.stem
                files += write_motion(
                    motion, out_dir / name, fps=generator.fps, audio_path=song, formats=formats, title=title,
                    floor_height=generator.floor_height,
                )  # fmt: skip
            report.written[str(song)] = files
        except DgsdpError as e:
            log.error("%s: %s", song, e)
            report.errors[str(song)] = str(e)
    return report


def print_report(report: GenerationReport) -> None:
    for song, files in report.written.items():
        print(f"{song}:")
        for f in files:
            print(f"  {f}")
    if report.errors:
        print(f"{len(report.errors)} song(s) failed:")
        for song, message in report.errors.items():
            print(f"  {song}: {message}")


@hydra.main(version_base="1.3", config_path=None, config_name=GENERATE_CONFIG_NAME)
def _main(cfg: DictConfig) -> None:
    report = run_main(generate, cfg)
    print_report(report)
    if not report.ok:
        raise SystemExit(1)


def main() -> None:
    with generate_configs():
        _main()


if __name__ == "__main__":
    main()
