"""Real-song benchmark: whole-song dances to songs the model never saw, measured against the targets of a usable
dance (no runaway speeds, feet on the floor, invisible long-form seams, motion on the beat).

Two commands:

``python -m dgsdp.benchmarks.realsongs prepare <out folder> [--sources DIR ...] [--max-songs N]`` picks a varied
set of real songs (tempo, loudness, length) from the given folders (by default where the Debian packages
``hyperrogue-music``, ``drascula-music`` and ``fb-music-high`` put their music) and writes, with ffmpeg, each
original and three hard versions of it: ``<song>-loud.wav`` (+20 dB, hard-clipped at full scale),
``<song>-8k.wav`` (8 kHz mono) and ``<song>-96k.wav`` (96 kHz), plus ``songs.json`` describing the set.

``python -m dgsdp.benchmarks.realsongs <folder> --checkpoint <ckpt> [overrides of conf/generate.yaml ...]``
dances to every audio file of the folder exactly as ``generate.py checkpoint=<ckpt> music=<song> style=<style>``
does (same config, same :meth:`DanceGenerator.dance_to_song` call; no files written) and prints, per song, at
30 FPS from the 24 SMPL joints (z-up metres): the p99.9 joint speed, the deepest penetration below the floor, the
fraction of frames floating above it, the seam ratio of the long-form window boundaries, the mean joint speed
against the training data's, the beat alignment score in two variants against the same motion shifted by half a
beat, and the mean speed by beat phase. Each song has two rows from the same sample: the raw model's (``cleanup=
false``) and the finished dance's (what generate.py writes, judged against the targets), and a line of what the
finishing changed, and a line of the song's beat by two trackers (librosa's, which the model hears, and the
independent one of :mod:`dgsdp.audio.beat_tracker`) with the dance's BAS on the independent beats; then a summary
line of the finished dances (a dance asked for in a genre judged against that genre's training dances; every
error a failure), one of the raw model's timing (its target needs the independent beats too), one of the
independent beats (where the trackers disagree, said rather than scored), one of the speed targets both ways
and one of the tempo folds. The metric functions below are plain numpy on joints (T, 24, 3).
"""

from dgsdp.benchmarks.realsongs.measures import (
    Reference,
    SongFigures,
    dance_figures,
    floating_fraction,
    p999_joint_speed,
    penetration_cm,
    phase_bins,
    phase_distance,
    seam_ratio,
    speed_by_phase,
    training_dances_passing,
    training_figures,
    window_boundaries,
    windowed_speed,
)
from dgsdp.benchmarks.realsongs.report import (
    SongResult,
    Tracking,
    format_row,
    genre_of,
    genre_speed_line,
    header,
    independent_summary,
    low_phase,
    raw_summary,
    style_plan,
    style_summary_lines,
    styles_for,
    summary_line,
    tempo_line,
)
from dgsdp.benchmarks.realsongs.run import main, run_benchmark
from dgsdp.benchmarks.realsongs.songs import SongInfo, analyse_song, pick_varied, prepare, song_family, write_versions
from dgsdp.metrics.beats import BAS_VARIANTS, BeatScores, beat_scores
from dgsdp.metrics.speed import mean_joint_speed

__all__ = [
    "BAS_VARIANTS", "low_phase", "phase_bins", "phase_distance", "raw_summary", "speed_by_phase",
    "BeatScores", "Reference", "SongFigures", "SongInfo", "SongResult", "Tracking", "independent_summary", "analyse_song", "beat_scores", "dance_figures",
    "floating_fraction", "format_row", "genre_of", "genre_speed_line", "header", "main", "mean_joint_speed", "p999_joint_speed", "penetration_cm",
    "pick_varied", "prepare", "run_benchmark", "seam_ratio", "song_family", "style_plan", "style_summary_lines",
    "styles_for", "summary_line", "tempo_line", "training_dances_passing", "training_figures", "window_boundaries", "windowed_speed", "write_versions",
]  # fmt: skip
