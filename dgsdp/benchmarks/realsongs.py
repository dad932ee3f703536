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
against the training data's, and the beat alignment score against the same motion shifted by half a beat; then a
summary line. The metric functions below are plain numpy on joints (T, 24, 3).
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.errors import ConfigError, DgsdpError
from dgsdp.metrics._common import MetricWarning, check_joints
from dgsdp.metrics.beats import beat_alignment_from_beats, motion_beats
from dgsdp.motion.skeleton import FOOT_JOINTS

FPS = 30
# The issue's targets for a dance a user would keep.
P999_SPEED_MAX_M_S = 8.0  # p99.9 joint speed below this
PENETRATION_MAX_CM = 3.0  # deepest joint at most this far below the floor
FLOATING_MAX_FRACTION = 0.10  # fraction of frames with the lowest foot joint > FLOATING_HEIGHT_M above the floor
FLOATING_HEIGHT_M = 0.10
SEAM_RATIO_MAX = 1.3  # speed around window boundaries / speed around any frame
CHECK_NAMES = ("p999", "penetration", "floating", "seam", "bas")  # the targets, in the order they are checked
SEAM_HALF_WIDTH_FRAMES = 2

# Where the Debian packages hyperrogue-music, drascula-music and fb-music-high (and frozen-bubble-data, which the
# last one comes with) install their music.
DEBIAN_MUSIC_DIRS = (
    "/usr/share/hyperrogue/music",
    "/usr/share/scummvm/drascula/audio",
    "/usr/share/games/frozen-bubble/snd",
)
TRACKER_SUFFIXES = (".xm", ".mod", ".it", ".s3m")  # tracker modules: decoded by ffmpeg (libopenmpt) when it can
VERSION_SUFFIXES = ("-loud", "-8k", "-96k")
LOUD_GAIN_DB = 20.0
MIN_SONG_SECONDS = 30.0  # shorter files in the source folders are jingles and sound effects
ANALYSIS_RATE_HZ = 11025
RARE_KIND_DISTANCE = 10.0  # in standard deviations of length, loudness and tempo (see pick_varied)


# --- metrics: joints (T, 24, 3), z-up metres, at ``fps`` ---------------------------------------------------------
def joint_speeds(joints: np.ndarray, fps: float = FPS) -> np.ndarray:
    """Speed of every joint between consecutive frames, (T-1, 24) in m/s."""
    positions = check_joints(joints, min_frames=2)
    return np.linalg.norm(np.diff(positions, axis=0), axis=-1) * fps


def p999_joint_speed(joints: np.ndarray, fps: float = FPS) -> float:
    """The 99.9th percentile of joint speed (m/s) over all joints and frames."""
    return float(np.percentile(joint_speeds(joints, fps), 99.9))


def mean_joint_speed(joints: np.ndarray, fps: float = FPS) -> float:
    """Mean joint speed (m/s) over all joints and frames."""
    return float(joint_speeds(joints, fps).mean())


def penetration_cm(joints: np.ndarray, floor_m: float = 0.0) -> float:
    """How far the lowest joint of the whole dance goes below the floor, in cm (0 if it never does)."""
    positions = check_joints(joints)
    return 100.0 * max(0.0, float(floor_m) - float(positions[..., 2].min()))


def floating_fraction(joints: np.ndarray, floor_m: float = 0.0, height_m: float = FLOATING_HEIGHT_M) -> float:
    """Fraction of frames whose lowest foot joint (ankles and toes, SMPL 7, 8, 10, 11) is more than ``height_m``
    above the floor."""
    positions = check_joints(joints)
    lowest_foot = positions[:, list(FOOT_JOINTS), 2].min(axis=1)
    return float(np.mean(lowest_foot - float(floor_m) > height_m))


def windowed_speed(joints: np.ndarray, fps: float = FPS, half_width: int = SEAM_HALF_WIDTH_FRAMES) -> np.ndarray:
    """Mean joint speed (m/s) within +-``half_width`` frames of every frame, (T,).

    For frame t it averages the joint-mean speeds of the steps between frames t - half_width .. t + half_width
    (2 * half_width steps; fewer at the ends of the dance, where the window is cut)."""
    speed = joint_speeds(joints, fps).mean(axis=1)  # (T-1,), step k is frames k -> k+1
    n_frames = len(speed) + 1
    cumulative = np.concatenate([[0.0], np.cumsum(speed)])
    t = np.arange(n_frames)
    lo = np.maximum(t - half_width, 0)
    hi = np.minimum(t + half_width, n_frames - 1)
    return (cumulative[hi] - cumulative[lo]) / (hi - lo)


def window_boundaries(n_frames: int, window: int, stride: int) -> np.ndarray:
    """Frames inside a dance of ``n_frames`` where a long-form window starts or ends (with the default 150-frame
    windows 75 apart: the multiples of 75)."""
    from dgsdp.generation.longform import WindowLayout

    layout = WindowLayout(n_frames, window, stride)
    edges = {s for s in layout.starts()} | {s + window for s in layout.starts()}
    return np.array(sorted(b for b in edges if 0 < b < n_frames), dtype=np.int64)


def seam_ratio(
    joints: np.ndarray, boundaries: Sequence[int], fps: float = FPS, half_width: int = SEAM_HALF_WIDTH_FRAMES
) -> float:
    """Mean over the window boundaries of the +-``half_width``-frame speed (:func:`windowed_speed`), divided by the
    same windowed speed averaged over every frame: 1.0 when boundaries look like any other moment. NaN without a
    boundary (a dance of one window) or without motion."""
    speed = windowed_speed(joints, fps, half_width)
    frames = np.asarray(boundaries, dtype=np.int64).reshape(-1)
    frames = frames[(frames >= 0) & (frames < len(speed))]
    overall = float(speed.mean())
    if frames.size == 0 or overall <= 0.0:
        return math.nan
    return float(speed[frames].mean()) / overall


@dataclass
class BeatScores:
    """BAS of a dance and of the same motion shifted later by ``shift_frames`` (half the median beat interval)."""

    bas: float
    shifted: float
    shift_frames: int
    n_music_beats: int

    @property
    def above_shifted(self) -> bool:
        return bool(self.bas > self.shifted)


def beat_scores(joints: np.ndarray, music_beats: Sequence[int], fps: float = FPS) -> BeatScores:
    """Beat alignment score (:mod:`dgsdp.metrics.beats`, Bailando variant) of a dance and of the same motion
    shifted later in time by half the median interval of the music beats (frame indices at ``fps``).

    Shifting the motion by h frames shifts its kinematic beats by h (those that leave the dance are dropped);
    music beats at or after the last speed sample are ignored, as in :func:`dgsdp.metrics.beats.beat_alignment`.
    With fewer than two music beats there is no beat interval: both scores are NaN."""
    positions = check_joints(joints, min_frames=2)
    n_frames = positions.shape[0]
    music = np.asarray(music_beats, dtype=np.int64).reshape(-1)
    music = music[(music >= 0) & (music < n_frames - 1)]
    if music.size < 2:
        return BeatScores(math.nan, math.nan, 0, int(music.size))
    shift = int(round(float(np.median(np.diff(np.sort(music)))) / 2.0))
    beats = motion_beats(positions, fps=fps)
    shifted = beats + shift
    shifted = shifted[shifted < n_frames - 1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MetricWarning)  # no motion beat at all: both scores are 0
        bas = beat_alignment_from_beats(beats, music, fps=fps)
        bas_shifted = beat_alignment_from_beats(shifted, music, fps=fps)
    return BeatScores(bas, bas_shifted, shift, int(music.size))


@dataclass
class SongFigures:
    """The benchmark's figures of one dance."""

    seconds: float
    p999_speed_m_s: float
    penetration_cm: float
    floating_fraction: float
    seam_ratio: float
    mean_speed_m_s: float
    bas: float
    bas_shifted: float
    bas_shift_frames: int
    n_music_beats: int
    n_boundaries: int

    def checks(self) -> dict[str, bool]:
        """Pass/fail per target (a dance of one window has no seams: its seam check passes)."""
        passed = (
            self.p999_speed_m_s < P999_SPEED_MAX_M_S,
            self.penetration_cm <= PENETRATION_MAX_CM,
            self.floating_fraction < FLOATING_MAX_FRACTION,
            math.isnan(self.seam_ratio) or self.seam_ratio < SEAM_RATIO_MAX,
            bool(self.bas > self.bas_shifted),
        )
        return dict(zip(CHECK_NAMES, passed, strict=True))


def dance_figures(
    joints: np.ndarray,
    *,
    music_beats: Sequence[int],
    boundaries: Sequence[int],
    floor_m: float = 0.0,
    fps: float = FPS,
) -> SongFigures:
    """Every figure of one dance, joints (T, 24, 3) z-up metres."""
    positions = check_joints(joints, min_frames=2)
    beats = beat_scores(positions, music_beats, fps)
    return SongFigures(
        seconds=positions.shape[0] / fps,
        p999_speed_m_s=p999_joint_speed(positions, fps),
        penetration_cm=penetration_cm(positions, floor_m),
        floating_fraction=floating_fraction(positions, floor_m),
        seam_ratio=seam_ratio(positions, boundaries, fps),
        mean_speed_m_s=mean_joint_speed(positions, fps),
        bas=beats.bas,
        bas_shifted=beats.shifted,
        bas_shift_frames=beats.shift_frames,
        n_music_beats=beats.n_music_beats,
        n_boundaries=len(boundaries),
    )


# --- the run's facts ---------------------------------------------------------------------------------------------
def training_figures(
    spec: Any,
    cache_dir: str | os.PathLike,
    *,
    floor_m: float = 0.0,
    window: int = 150,
    stride: int = 75,
    progress: bool = False,
) -> tuple[dict[str, float] | None, str]:
    """The benchmark's figures on the data a run was trained on (its config's ``data.root``, train split, read with
    the project's loader), the reference for the dances: mean joint speed over every frame of every dance, p99.9
    joint speed, deepest penetration, floating fraction over every frame, and the mean seam ratio of the dances
    with long-form window boundaries laid on them (about 1.0: real dances have no seams). Cached in
    ``cache_dir/realsongs``. Returns (figures, where they came from), or (None, why) without the data."""
    from dgsdp.data.aistpp import read_split
    from dgsdp.data.datamodule import load_sequences
    from dgsdp.utils.io import atomic_write_text, stable_hash

    data = (getattr(spec, "record", None) or {}).get("data") or {}
    root = data.get("root")
    if not root or not (Path(root) / "motions").is_dir():
        return None, f"training data not found (data.root={root!r}); give --train-speed"
    root = Path(root)
    split = str(data.get("train_split", "train"))
    fps = int(data.get("fps", FPS))
    try:
        names = read_split(root, split)
    except DgsdpError as e:
        return None, f"training split unreadable: {e}"
    stamps = []  # the cached figures are recomputed when a motion file changes
    for name in names:
        pkl = root / "motions" / f"{name}.pkl"
        stamps.append([name, [pkl.stat().st_size, pkl.stat().st_mtime_ns] if pkl.is_file() else None])
    settings = {"floor_m": float(floor_m), "window": int(window), "stride": int(stride), "fps": fps}
    key = stable_hash({"root": str(root.resolve()), "split": split, "files": stamps, **settings})
    cache_file = Path(cache_dir) / "realsongs" / f"train-figures-{key}.json"
    if cache_file.is_file():
        try:
            return dict(json.loads(cache_file.read_text())["figures"]), f"{root} ({split}, cached)"
        except (ValueError, KeyError, TypeError):
            pass  # a damaged cache file is recomputed
    import torch

    from dgsdp.motion import pose_to_joints

    try:
        sequences = load_sequences(root, split, fps=fps, cache_dir=cache_dir, progress=progress)
    except DgsdpError as e:
        return None, f"training data unreadable: {e}"
    speeds, floating, seams, penetration, frames = [], 0.0, [], 0.0, 0
    for seq in sequences:
        if len(seq.motion) < 2:
            continue
        joints = pose_to_joints(torch.from_numpy(np.asarray(seq.motion, dtype=np.float64))).numpy()
        speeds.append(joint_speeds(joints, fps).reshape(-1))
        floating += floating_fraction(joints, floor_m) * len(joints)
        frames += len(joints)
        penetration = max(penetration, penetration_cm(joints, floor_m))
        boundaries = window_boundaries(len(joints), window, stride)
        if boundaries.size:
            seams.append(seam_ratio(joints, boundaries, fps))
    if not speeds:
        return None, f"no training dance of two frames or more in {root} ({split})"
    pooled = np.concatenate(speeds)
    figures = {
        "mean_speed_m_s": float(pooled.mean()),
        "p999_speed_m_s": float(np.percentile(pooled, 99.9)),
        "penetration_cm": penetration,
        "floating_fraction": floating / frames,
        "seam_ratio": float(np.nanmean(seams)) if seams else math.nan,
        "n_dances": len(speeds),
        "seconds": frames / fps,
    }
    record = {"figures": figures, "root": str(root), "split": split, **settings}
    atomic_write_text(cache_file, json.dumps(_no_nan(record)))
    return figures, f"{root} ({split})"


# --- song set ----------------------------------------------------------------------------------------------------
@dataclass
class SongInfo:
    """A candidate song: its file, length, loudness and tempo."""

    path: str
    name: str
    seconds: float
    rms_dbfs: float
    peak_dbfs: float
    tempo_bpm: float
    decoder: str  # ffmpeg, or "loader" when only the project's loader (libsndfile) reads it


def _require_ffmpeg() -> str:
    exe = shutil.which("ffmpeg")
    if exe is None:
        raise ConfigError("the song set is built with ffmpeg: install it (e.g. apt-get install ffmpeg)")
    return exe


def ffmpeg_decode(path: Path, rate_hz: int) -> np.ndarray | None:
    """Mono float32 samples of ``path`` at ``rate_hz`` decoded by ffmpeg, or None when ffmpeg cannot decode it."""
    cmd = [_require_ffmpeg(), "-nostdin", "-v", "error", "-i", str(path), "-ac", "1", "-ar", str(rate_hz)]
    cmd += ["-f", "f32le", "-"]
    result = subprocess.run(cmd, capture_output=True, check=False)
    if result.returncode != 0 or not result.stdout:
        return None
    return np.frombuffer(result.stdout, dtype="<f4")


def _song_label(path: Path) -> str:
    """``<collection>-<stem>``: the collection is the nearest folder above the file with a specific name."""
    generic = {"music", "audio", "snd", "sound", "sounds", "songs", "ogg", "share", "games", "usr"}
    collection = next((p.name for p in path.parents if p.name and p.name.lower() not in generic), "")
    stem = path.stem
    first_word = re.split(r"[-_ ]", collection.lower())[0]
    name = stem if not collection or stem.lower().startswith(first_word) else f"{collection}-{stem}"
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "song"


def _dbfs(amplitude: float) -> float:
    return 20.0 * math.log10(max(amplitude, 1e-10))


def analyse_song(path: Path) -> SongInfo | None:
    """Length, loudness and tempo of a file (ffmpeg, else the project's loader); None if nothing decodes it."""
    import librosa

    samples = ffmpeg_decode(path, ANALYSIS_RATE_HZ)
    decoder = "ffmpeg"
    if samples is None or samples.size == 0:
        from dgsdp.audio import load_audio

        try:
            samples, _ = load_audio(path, ANALYSIS_RATE_HZ)
        except DgsdpError:
            return None
        decoder = "loader"
    seconds = samples.size / ANALYSIS_RATE_HZ
    rms = float(np.sqrt(np.mean(np.square(samples, dtype=np.float64))))
    peak = float(np.abs(samples).max())
    tempo = math.nan
    if seconds >= 5.0:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            envelope = librosa.onset.onset_strength(y=samples, sr=ANALYSIS_RATE_HZ, hop_length=256)
            tempo = float(np.atleast_1d(librosa.feature.tempo(onset_envelope=envelope, sr=ANALYSIS_RATE_HZ,
                                                               hop_length=256))[0])  # fmt: skip
    return SongInfo(str(path), _song_label(path), seconds, _dbfs(rms), _dbfs(peak), tempo, decoder)


def pick_varied(songs: Sequence[SongInfo], n: int) -> list[SongInfo]:
    """``n`` songs spread over length (log seconds), loudness (RMS dBFS), tempo and kind of file (tracker module,
    readable by the project's loader only): the longest first, then each time the song farthest (in standardised
    units) from all those picked; another kind of file counts as far, so that each kind comes early.
    Deterministic for given songs."""
    if n <= 0 or not songs:
        return []
    kinds = [(Path(s.path).suffix.lower() in TRACKER_SUFFIXES, s.decoder == "loader") for s in songs]
    feats = np.array(
        [[math.log(s.seconds), s.rms_dbfs, s.tempo_bpm, *kind] for s, kind in zip(songs, kinds)], dtype=np.float64
    )
    feats = np.where(np.isfinite(feats), feats, np.nanmean(np.where(np.isfinite(feats), feats, np.nan), axis=0))
    measured = feats[:, :3]
    scale = measured.std(axis=0)
    feats[:, :3] = (measured - measured.mean(axis=0)) / np.where(scale > 0, scale, 1.0)
    feats[:, 3:] *= RARE_KIND_DISTANCE  # farther than any two songs of one kind: each kind is picked early
    order = sorted(range(len(songs)), key=lambda i: (-songs[i].seconds, songs[i].path))
    picked = [order[0]]
    while len(picked) < min(n, len(songs)):
        dist = np.min(np.linalg.norm(feats[:, None, :] - feats[None, picked, :], axis=-1), axis=1)
        dist[picked] = -1.0
        best = max(order, key=lambda i: (dist[i], -order.index(i)))
        picked.append(best)
    return [songs[i] for i in picked]


def _ffmpeg(args: list[str], out: Path) -> None:
    """Run ffmpeg writing a wav to ``out`` atomically; a DgsdpError with ffmpeg's message when it fails."""
    from dgsdp.utils.io import atomic_path

    with atomic_path(out) as tmp:
        cmd = [_require_ffmpeg(), "-nostdin", "-y", "-v", "error", *args, "-f", "wav", str(tmp)]
        result = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if result.returncode != 0:
            raise DgsdpError(f"ffmpeg failed writing {out.name}: {result.stderr.strip()[-500:]}")


def _wav_facts(path: Path) -> dict[str, Any]:
    import soundfile as sf

    data, rate_hz = sf.read(str(path), dtype="int16", always_2d=True)
    full = np.abs(data.astype(np.int32)) >= 32767
    return {
        "rate_hz": int(rate_hz),
        "channels": int(data.shape[1]),
        "peak_dbfs": round(20.0 * math.log10(max(int(np.abs(data.astype(np.int32)).max()), 1) / 32768.0), 3),
        "clipped_fraction": round(float(full.mean()), 5),
    }


def write_versions(song: SongInfo, out: Path) -> dict[str, Any]:
    """Write the original and its loud, 8 kHz mono and 96 kHz versions of one song into ``out``."""
    import soundfile as sf

    from dgsdp.audio import load_audio
    from dgsdp.audio.io import AUDIO_SUFFIXES
    from dgsdp.utils.io import atomic_path

    source = Path(song.path)
    files: dict[str, Any] = {}
    decoded: Path | None = None
    if source.suffix.lower() in AUDIO_SUFFIXES:
        original = out / f"{song.name}{source.suffix.lower()}"
        with atomic_path(original) as tmp:
            shutil.copyfile(source, tmp)
    else:  # e.g. a tracker module: the project reads wav, mp3, ogg and flac
        original = out / f"{song.name}.wav"
        _ffmpeg(["-i", str(source), "-c:a", "pcm_s16le"], original)
    files["original"] = {"file": original.name}
    ffmpeg_input = source
    if song.decoder == "loader":  # ffmpeg cannot read it: decode with the project's loader for ffmpeg
        data, rate_hz = load_audio(source, None, mono=False)
        decoded = out / f".{song.name}-decoded.wav"
        with atomic_path(decoded) as tmp:
            sf.write(str(tmp), data.T, rate_hz, subtype="FLOAT", format="WAV")
        ffmpeg_input = decoded
    try:
        loud = out / f"{song.name}-loud.wav"
        _ffmpeg(["-i", str(ffmpeg_input), "-af", f"volume={LOUD_GAIN_DB:g}dB,asoftclip=type=hard:threshold=1",
                 "-c:a", "pcm_s16le"], loud)  # fmt: skip
        files["loud"] = {"file": loud.name, **_wav_facts(loud)}
        low = out / f"{song.name}-8k.wav"
        _ffmpeg(["-i", str(ffmpeg_input), "-ac", "1", "-ar", "8000", "-c:a", "pcm_s16le"], low)
        files["8k"] = {"file": low.name, **_wav_facts(low)}
        high = out / f"{song.name}-96k.wav"
        _ffmpeg(["-i", str(ffmpeg_input), "-ar", "96000", "-c:a", "pcm_s16le"], high)
        files["96k"] = {"file": high.name, **_wav_facts(high)}
    finally:
        if decoded is not None:
            decoded.unlink(missing_ok=True)
    return files


def prepare(out: Path, sources: Sequence[str], max_songs: int, min_seconds: float = MIN_SONG_SECONDS) -> int:
    """Build the song set in ``out`` (see the module docstring); returns the exit code."""
    from dgsdp.audio.io import AUDIO_SUFFIXES
    from dgsdp.utils.io import atomic_write_text

    _require_ffmpeg()
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"{out} is not an empty folder: give a new or empty folder for the song set")
    suffixes = (*AUDIO_SUFFIXES, *TRACKER_SUFFIXES)
    files = [f for d in sources for f in sorted(Path(d).glob("*")) if f.is_file() and f.suffix.lower() in suffixes]
    missing = [d for d in sources if not Path(d).is_dir()]
    for d in missing:
        print(f"source folder {d} does not exist: skipped", file=sys.stderr)
    if not files:
        raise ConfigError(f"no audio files in {', '.join(sources)}; give --sources with folders of songs")
    candidates: dict[str, SongInfo] = {}
    skipped: list[str] = []
    for k, path in enumerate(files, 1):
        print(f"[{k}/{len(files)}] analysing {path}", file=sys.stderr, flush=True)
        info = analyse_song(path)
        if info is None:
            skipped.append(f"{path}: neither ffmpeg nor the project's loader decodes it")
            continue
        if info.seconds < min_seconds:
            continue
        if info.decoder == "loader":
            print(f"  ffmpeg cannot decode {path.name}; the project's loader reads it", file=sys.stderr)
        previous = candidates.get(info.name)
        # one file per song: a tracker module (the composition itself) over its rendering
        if previous is None or Path(info.path).suffix.lower() in TRACKER_SUFFIXES:
            candidates[info.name] = info
    if not candidates:
        raise ConfigError(f"no song of at least {min_seconds:g} s in {', '.join(sources)}")
    chosen = pick_varied(list(candidates.values()), max_songs)
    out.mkdir(parents=True, exist_ok=True)
    manifest: dict[str, Any] = {
        "sources": list(sources),
        "loud_gain_db": LOUD_GAIN_DB,
        "skipped": skipped,
        "candidates": [asdict(c) for c in candidates.values()],
        "songs": [],
    }
    for k, song in enumerate(chosen, 1):
        print(f"[{k}/{len(chosen)}] writing {song.name} ({song.seconds:.0f} s)", file=sys.stderr, flush=True)
        try:
            entry = {**asdict(song), "files": write_versions(song, out)}
        except DgsdpError as e:  # this song is left out whole; the others go on
            for f in out.glob(f"{glob.escape(song.name)}*"):
                if song_family(f) == song.name:
                    f.unlink()
            skipped.append(f"{song.path}: {e}")
            print(f"  {song.name} left out: {e}", file=sys.stderr)
            continue
        loud = entry["files"]["loud"]
        if loud["clipped_fraction"] <= 0:
            print(f"  warning: {song.name}-loud.wav does not clip (peak {loud['peak_dbfs']} dBFS)", file=sys.stderr)
        manifest["songs"].append(entry)
    atomic_write_text(out / "songs.json", json.dumps(manifest, indent=2) + "\n")
    print(f"{'song':<28} {'source':<10} {'sec':>6} {'rms_db':>7} {'peak_db':>7} {'bpm':>6} {'loud_clip%':>10}")
    for entry in manifest["songs"]:
        print(
            f"{entry['name']:<28} {entry['decoder']:<10} {entry['seconds']:6.1f} {entry['rms_dbfs']:7.1f} "
            f"{entry['peak_dbfs']:7.1f} {entry['tempo_bpm']:6.1f} {100 * entry['files']['loud']['clipped_fraction']:10.2f}"
        )
    for line in skipped:
        print(f"skipped: {line}")
    print(f"wrote {len(chosen)} songs x 4 versions to {out} (songs.json describes them)")
    return 0


# --- benchmark ---------------------------------------------------------------------------------------------------
def song_family(path: Path) -> str:
    """The original song's name of a file of the set (``x-loud.wav`` -> ``x``)."""
    stem = path.stem
    for suffix in VERSION_SUFFIXES:
        if stem.endswith(suffix):
            return stem[: -len(suffix)]
    return stem


def styles_for(songs: Sequence[Path], genres: Sequence[str | None], style: str | None) -> list[str | None]:
    """The style of each song: ``style`` for all, or the genres in turn, one per original song (its loud and
    resampled versions get the same genre, so that versions compare)."""
    if style is not None:
        return [style] * len(songs)
    families = sorted({song_family(s) for s in songs})
    return [genres[families.index(song_family(s)) % len(genres)] for s in songs]


def style_plan(
    songs: Sequence[Path], genres: Sequence[str | None], style: str | None, all_styles: bool = False
) -> list[tuple[Path, str | None]]:
    """The dances to make, (song, style) pairs: each song in its style from :func:`styles_for`, or with
    ``all_styles`` each song in every genre of the checkpoint, song by song."""
    if all_styles:
        if style is not None:
            raise ConfigError("--all-styles dances every song in every genre: leave out --style")
        if all(g is None for g in genres):
            raise ConfigError("--all-styles needs a model with a style embedding; this checkpoint has no genres")
        return [(song, genre) for song in songs for genre in genres]
    return list(zip(songs, styles_for(songs, genres, style)))


@dataclass
class SongResult:
    name: str
    style: str | None
    figures: SongFigures | None = None
    feature_seconds: float = math.nan
    dance_seconds: float = math.nan
    error: str | None = None
    checks: dict[str, bool] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.error is None and all(self.checks.values())


def _no_nan(value: Any) -> Any:
    """``value`` with every NaN replaced by None (null in JSON)."""
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, dict):
        return {k: _no_nan(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_no_nan(v) for v in value]
    return value


def _fmt(value: float, spec: str) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def header(width: int = 30) -> str:
    return (
        f"{'song':<{width}} {'style':<6} {'sec':>6} {'p999':>6} {'pen_cm':>6} {'float':>6} {'seam':>5} {'speed':>6} "
        f"{'ratio':>5} {'bas':>5} {'bas_sh':>6} {'gen_s':>6}  result"
    )


def format_row(result: SongResult, train_speed: float, width: int = 30) -> str:
    if result.error is not None:
        return f"{result.name:<{width}} {str(result.style):<6} ERROR: {result.error}"
    f = result.figures
    failed = [name for name, ok in result.checks.items() if not ok]
    verdict = "pass" if not failed else "FAIL(" + ",".join(failed) + ")"
    ratio = f.mean_speed_m_s / train_speed if train_speed and not math.isnan(train_speed) else math.nan
    return (
        f"{result.name:<{width}} {str(result.style):<6} {f.seconds:6.1f} {f.p999_speed_m_s:6.2f} {f.penetration_cm:6.1f} "
        f"{f.floating_fraction:6.3f} {_fmt(f.seam_ratio, '5.2f'):>5} {f.mean_speed_m_s:6.3f} {_fmt(ratio, '5.2f'):>5} "
        f"{_fmt(f.bas, '5.3f'):>5} {_fmt(f.bas_shifted, '6.3f'):>6} {result.dance_seconds:6.1f}  {verdict}"
    )


def summary_line(results: Sequence[SongResult], train_speed: float) -> str:
    done = [r for r in results if r.error is None]
    figs = [r.figures for r in done]

    def worst(values: list[float], fn: Any = max) -> str:
        values = [v for v in values if not math.isnan(v)]
        return _fmt(fn(values), ".3f") if values else "n/a"

    ratios = [f.mean_speed_m_s / train_speed for f in figs] if train_speed and not math.isnan(train_speed) else []
    gen = [r.dance_seconds / r.figures.seconds for r in done if r.figures.seconds > 0]
    return (
        f"songs={len(results)} pass={sum(r.passed for r in results)} errors={len(results) - len(done)} "
        f"worst_p999={worst([f.p999_speed_m_s for f in figs])} worst_pen_cm={worst([f.penetration_cm for f in figs])} "
        f"worst_float={worst([f.floating_fraction for f in figs])} worst_seam={worst([f.seam_ratio for f in figs])} "
        f"bas_above_shifted={sum(r.checks.get('bas', False) for r in done)}/{len(done)} "
        f"speed_ratio_mean={_fmt(float(np.mean(ratios)) if ratios else math.nan, '.3f')} "
        f"train_speed={_fmt(train_speed, '.3f')} gen_s_per_dance_s={_fmt(float(np.mean(gen)) if gen else math.nan, '.2f')}"
    )


def style_summary_lines(results: Sequence[SongResult]) -> list[str]:
    """One line per style: how many of its dances pass, each target's misses, and its worst p99.9 speed."""
    lines = []
    for style in dict.fromkeys(r.style for r in results):
        mine = [r for r in results if r.style == style]
        done = [r for r in mine if r.error is None]
        missed = {name: sum(not r.checks.get(name, True) for r in done) for name in CHECK_NAMES}
        p999 = [r.figures.p999_speed_m_s for r in done]
        lines.append(
            f"style={style} dances={len(mine)} pass={sum(r.passed for r in mine)} errors={len(mine) - len(done)} "
            + " ".join(f"{name}_missed={n}" for name, n in missed.items())
            + f" worst_p999={_fmt(max(p999) if p999 else math.nan, '.3f')}"
        )
    return lines


def run_benchmark(
    folder: Path,
    checkpoint: str,
    overrides: Sequence[str] = (),
    *,
    style: str | None = None,
    all_styles: bool = False,
    floor_m: float | None = None,
    train_speed: float | None = None,
    json_path: Path | None = None,
    motions_dir: Path | None = None,
    out: Any = None,
) -> list[SongResult]:
    """Dance to every song of ``folder`` as generate.py would and print the table and the summary line (to ``out``,
    default stdout; progress goes to stderr). ``all_styles``: every song in every genre of the checkpoint (a row and
    a dance each), and a summary line per genre after the summary line."""
    import torch

    from dgsdp.cli.config import compose_config
    from dgsdp.cli.generate import GenerateJob
    from dgsdp.generation.beatsync import song_beats
    from dgsdp.generation.pipeline import find_songs, write_motion
    from dgsdp.motion import pose_to_joints

    out = sys.stdout if out is None else out
    if not folder.is_dir():
        raise ConfigError(f"{folder} is not a folder of songs (build one with: python -m {__spec__.name} prepare DIR)")
    cfg = compose_config("generate", [f"checkpoint={checkpoint}", *overrides])
    songs = find_songs(str(folder))
    job = GenerateJob.from_config(cfg)
    generator, sampling = job.generator, job.sampling
    window = min(sampling.window_frames or generator.window, generator.model.denoiser.seq_len)
    stride = min(sampling.stride_frames, window)
    floor = generator.floor_height if floor_m is None else float(floor_m)
    reference, train_source = training_figures(
        generator.spec, cfg.paths.cache_dir, floor_m=floor, window=window, stride=stride
    )
    if train_speed is not None:
        train_source = "--train-speed"
    else:
        train_speed = math.nan if reference is None else float(reference["mean_speed_m_s"])
    genres: list[str | None] = [None]
    if generator.style_dim:
        genres = list(generator.embedder().vocab.codes)
    dances = style_plan(songs, genres, None if style is None else str(style), all_styles)
    plans: dict[str | None, Any] = {}
    print(
        f"checkpoint {checkpoint}; {len(songs)} songs in {folder}; sampling {sampling.method}-{sampling.steps} "
        f"guidance music={sampling.guidance.music:g}; windows {window} frames, stride {stride}; floor z={floor:g} m; "
        f"training mean joint speed {_fmt(train_speed, '.3f')} m/s from {train_source}",
        file=out,
    )
    if reference is not None:
        r = reference
        print(
            f"training data ({r['n_dances']:g} dances, {r['seconds']:.0f} s) on the same measures: "
            f"p999={r['p999_speed_m_s']:.2f} pen_cm={r['penetration_cm']:.1f} float={r['floating_fraction']:.3f} "
            f"seam={_fmt(r['seam_ratio'], '.2f')} speed={r['mean_speed_m_s']:.3f}",
            file=out,
        )
    width = max([len(s.name) for s in songs] + [4])
    print(header(width), file=out, flush=True)
    results: list[SongResult] = []
    for k, (song, song_style) in enumerate(dances, 1):
        print(f"[{k}/{len(dances)}] {song.name} (style {song_style})", file=sys.stderr, flush=True)
        result = SongResult(song.name, song_style)
        try:
            if song_style not in plans:
                plans[song_style] = generator.resolve_style(song_style)
            start = time.perf_counter()
            generator.music_features(song, cfg.seconds)  # features first (cached), so that the dance time is sampling
            beats = song_beats(song, generator.cache, generator.audio_encoder)
            result.feature_seconds = time.perf_counter() - start
            start = time.perf_counter()
            motions = job.dance(song, plans[song_style])
            result.dance_seconds = time.perf_counter() - start
            if motions_dir is not None:
                name = f"{song.stem}__{song_style}" if all_styles else song.stem
                write_motion(motions[0], motions_dir / name, fps=generator.fps, formats=["npy"])
            joints = pose_to_joints(motions[0].double()).numpy()
            boundaries = window_boundaries(len(joints), window, stride)
            result.figures = dance_figures(joints, music_beats=beats, boundaries=boundaries, floor_m=floor)
            result.checks = result.figures.checks()
        except (DgsdpError, torch.cuda.OutOfMemoryError) as e:
            result.error = str(e).replace("\n", " ")
        results.append(result)
        print(format_row(result, train_speed, width), file=out, flush=True)
    print(summary_line(results, train_speed), file=out, flush=True)
    if all_styles:
        print("\n".join(style_summary_lines(results)), file=out, flush=True)
    if json_path is not None:
        from dgsdp.utils.io import atomic_write_text

        payload = {
            "folder": str(folder),
            "checkpoint": str(checkpoint),
            "overrides": list(overrides),
            "all_styles": all_styles,
            "floor_m": floor,
            "train_speed_m_s": None if math.isnan(train_speed) else train_speed,
            "train_speed_source": train_source,
            "training_data_figures": reference,
            "window_frames": window,
            "stride_frames": stride,
            "thresholds": {
                "p999_speed_m_s_below": P999_SPEED_MAX_M_S,
                "penetration_cm_at_most": PENETRATION_MAX_CM,
                "floating_fraction_below": FLOATING_MAX_FRACTION,
                "floating_height_m": FLOATING_HEIGHT_M,
                "seam_ratio_below": SEAM_RATIO_MAX,
            },
            "songs": [
                {
                    "name": r.name,
                    "style": r.style,
                    "error": r.error,
                    "feature_seconds": r.feature_seconds,
                    "dance_seconds": r.dance_seconds,
                    "figures": None if r.figures is None else asdict(r.figures),
                    "speed_ratio": None
                    if r.figures is None or math.isnan(train_speed)
                    else r.figures.mean_speed_m_s / train_speed,
                    "checks": r.checks,
                    "passed": r.passed,
                }
                for r in results
            ],
            "summary": summary_line(results, train_speed),
        }
        atomic_write_text(json_path, json.dumps(_no_nan(payload), indent=2, allow_nan=False) + "\n")
    return results


def _prepare_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog=f"python -m {__spec__.name if __spec__ else 'dgsdp.benchmarks.realsongs'} prepare",
        description="Build the real-song set: varied originals plus loud (+20 dB, clipped), 8 kHz mono and "
        "96 kHz versions, written with ffmpeg.",
    )
    parser.add_argument("out", type=Path, help="folder to write the song set into")
    parser.add_argument(
        "--sources", nargs="+", default=list(DEBIAN_MUSIC_DIRS),
        help="folders of songs (default: where the Debian packages hyperrogue-music, drascula-music and "
        "fb-music-high install theirs)",
    )  # fmt: skip
    parser.add_argument("--max-songs", type=int, default=8, help="how many originals to pick (default 8)")
    parser.add_argument("--min-seconds", type=float, default=MIN_SONG_SECONDS, help="shortest song to consider")
    args = parser.parse_args(argv)
    return prepare(args.out, args.sources, args.max_songs, args.min_seconds)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] == "prepare":
            return _prepare_main(argv[1:])
        parser = argparse.ArgumentParser(
            prog=f"python -m {__spec__.name if __spec__ else 'dgsdp.benchmarks.realsongs'}",
            description="Dance to every song of a folder as generate.py does and measure the dances "
            "(build a song set first with the 'prepare' command).",
        )
        parser.add_argument("folder", type=Path, help="folder of songs (wav, mp3, ogg, flac)")
        parser.add_argument("overrides", nargs="*", help="overrides of conf/generate.yaml, e.g. sampling.steps=10")
        parser.add_argument("--checkpoint", required=True, help="a trained model's .ckpt file")
        parser.add_argument("--style", default=None, help="one style for all songs (default: the checkpoint's "
                            "genres in turn, one per original song)")  # fmt: skip
        parser.add_argument("--all-styles", action="store_true", help="dance every song in every genre of the "
                            "checkpoint (a row each) and print a summary line per genre")  # fmt: skip
        parser.add_argument("--floor", type=float, default=None, help="floor height in metres (default: the run's)")
        parser.add_argument(
            "--train-speed",
            type=float,
            default=None,
            help="the training data's mean joint speed in m/s (default: computed from its data)",
        )
        parser.add_argument("--json", type=Path, default=None, help="write every figure to this JSON file")
        parser.add_argument("--motions", type=Path, default=None,
                            help="also write each dance (T, 151) as <folder>/<song>.npy (<song>__<style>.npy with "
                            "--all-styles), e.g. to render it later")  # fmt: skip
        args = parser.parse_intermixed_args(argv)
        run_benchmark(
            args.folder, args.checkpoint, args.overrides, style=args.style, all_styles=args.all_styles,
            floor_m=args.floor, train_speed=args.train_speed, json_path=args.json, motions_dir=args.motions,
        )  # fmt: skip
        return 0
    except DgsdpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
