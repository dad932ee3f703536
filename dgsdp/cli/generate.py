"""``python generate.py``: dance to songs with a trained checkpoint, optionally editing a given motion.

Reads the checkpoint, the style and any given motion once (a problem with them stops the run with one clear
message), then generates every song; a song that fails (undecodable, too long, keyframes outside it, ...) is
reported at the end while the other songs are still written. The exit code is non-zero if anything failed.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig, OmegaConf

from dgsdp.cli.config import GENERATE_CONFIG_NAME, as_list, generate_configs
from dgsdp.cli.runtime import run_main
from dgsdp.editing import check_task
from dgsdp.errors import ConfigError
from dgsdp.export import check_formats
from dgsdp.generation.pipeline import TEXT_READING_OFF, EditSettings, Finishing, TextReadingChoice
from dgsdp.generation.songs import GenerateSettings, GenerationReport, dance_songs
from dgsdp.sampling import SamplingSettings

log = logging.getLogger(__name__)


def edit_settings(cfg: DictConfig) -> EditSettings:
    """The editing task and where its given motion is (read by the generator; one clear error for a bad file)."""
    task = check_task(cfg.task)
    file = {"seed_motion": cfg.seed_motion_file, "inbetween": cfg.seed_motion_file}.get(task)
    if task == "keyframes":
        file = cfg.keyframes_file
    file = file or cfg.motion_file
    if task != "none" and not file:
        raise ConfigError(
            f"task={task} needs the given motion: set seed_motion_file (seed_motion, inbetween), "
            "keyframes_file (keyframes) or motion_file (any task); .npy (N, D) pose vectors or AIST++ .pkl"
        )
    return EditSettings(
        task=task,
        motion_file=str(file) if file else None,
        seed_frames=int(cfg.seed_frames),
        end_frames=int(cfg.end_frames),
        inpaint_fraction=float(cfg.inpaint_fraction),
        joints=as_list(cfg.joints),
        with_root=bool(cfg.with_root),
        keyframes=[int(k) for k in as_list(cfg.keyframes) or []] or None,
        keyframe_seconds=[float(s) for s in as_list(cfg.keyframe_seconds) or []] or None,
    )


def finishing_settings(node: Any) -> Finishing:
    """The ``finishing`` node of a generate config as checked :class:`Finishing` limits (defaults for absent keys)."""
    if node is None:
        return Finishing()
    values = OmegaConf.to_container(node) if isinstance(node, DictConfig) else node
    if not isinstance(values, dict):
        raise ConfigError(f"finishing must be a mapping of limits, got {values!r}")
    known = {f.name for f in dataclasses.fields(Finishing)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"finishing has no key {', '.join(unknown)}; its keys: {', '.join(sorted(known))}")
    for key, value in values.items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)):
            raise ConfigError(f"finishing.{key} must be a number (or null to lift the limit), got {value!r}")
    if values.get("beat_sync_reach", 0.25) is None:
        raise ConfigError(
            "finishing.beat_sync_reach must be a number of beats; beat_sync=false keeps the model's timing"
        )
    return Finishing(**values)


def text_reading_setting(cfg: DictConfig) -> TextReadingChoice | None:
    """generate.py's ``style_text_reading``, ``style_text_temperature`` and ``style_text_descriptions``: None (all
    null: the checkpoint's choice) or a checked choice (YAML 1.1 reads ``off`` as false)."""
    how, temperature = cfg.get("style_text_reading"), cfg.get("style_text_temperature")
    descriptions = cfg.get("style_text_descriptions")
    how = TEXT_READING_OFF if how is False else how
    temperature = TEXT_READING_OFF if temperature is False else temperature
    if how is None and temperature is None and descriptions is None:
        return None
    return TextReadingChoice.make(
        None if how is None else str(how), temperature, None if descriptions is None else str(descriptions)
    )


def generate_settings(cfg: DictConfig) -> GenerateSettings:
    """A composed ``generate`` config as checked plain settings (every problem with it before any work)."""
    if not cfg.get("checkpoint"):
        raise ConfigError("give checkpoint=<path of a trained model's .ckpt file>")
    music = as_list(cfg.music) if not isinstance(cfg.music, str) else [cfg.music]  # checked by find_songs
    if cfg.seconds is not None and float(cfg.seconds) <= 0:
        raise ConfigError(f"seconds must be positive (the length of song to dance to), got {cfg.seconds}")
    for key, what in (("cleanup", "feet on the floor"), ("beat_sync", "pauses retimed onto the beats")):
        value = cfg.get(key, True)
        if not isinstance(value, bool):
            raise ConfigError(f"{key} must be true or false ({what}), got {value!r}")
    if int(cfg.num_samples) < 1:
        raise ConfigError(f"num_samples must be at least 1, got {cfg.num_samples}")
    return GenerateSettings(
        checkpoint=str(cfg.checkpoint),
        music=[str(m) for m in music or []],
        style=None if cfg.style is None else str(cfg.style),
        output_dir=Path(cfg.output_dir).expanduser(),
        cache_dir=str(cfg.paths.cache_dir),
        formats=check_formats([str(f) for f in as_list(cfg.formats) or []]),
        sampling=SamplingSettings.from_config(cfg.sampling),
        edit=edit_settings(cfg),
        device=str(cfg.device),
        max_song_seconds=None if cfg.max_song_seconds is None else float(cfg.max_song_seconds),
        cleanup=cfg.get("cleanup", True),
        beat_sync=cfg.get("beat_sync", True),
        finishing=finishing_settings(cfg.get("finishing")),
        seconds=None if cfg.seconds is None else float(cfg.seconds),
        blend_seconds=float(cfg.schedule_blend_seconds),
        style_text=text_reading_setting(cfg),
        num_samples=int(cfg.num_samples),
        seed=int(cfg.seed),
        progress=bool(cfg.progress),
    )


def generate(cfg: DictConfig) -> GenerationReport:
    """Run one generation job from a composed ``generate`` config; returns what was written and what failed."""
    settings = generate_settings(cfg)
    return dance_songs(settings)


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
