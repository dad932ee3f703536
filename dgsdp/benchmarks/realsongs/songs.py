"""The real-song benchmark's songs: finding, analysing and picking a varied set, and writing its hard versions
(loud, 8 kHz, 96 kHz) with ffmpeg."""

from __future__ import annotations

import glob
import json
import math
import re
import shutil
import subprocess
import sys
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.errors import ConfigError, DgsdpError

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
    from dgsdp.audio.numba_cache import librosa

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


def prepare(
    out: Path,
    sources: Sequence[str],
    max_songs: int,
    min_seconds: float = MIN_SONG_SECONDS,
    exclude: Sequence[Path] = (),
) -> int:
    """Build the song set in ``out`` (see the module docstring); returns the exit code. ``exclude``: song sets
    (folders) whose songs this set must not share, so that settings tuned on one are reported on another."""
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
    taken = set()
    for folder in exclude:
        if not Path(folder).is_dir():
            raise ConfigError(f"--exclude {folder}: not a folder of songs")
        taken |= {song_family(f) for f in Path(folder).iterdir() if f.suffix.lower() in suffixes}
    candidates: dict[str, SongInfo] = {}
    skipped: list[str] = []
    for k, path in enumerate(files, 1):
        print(f"[{k}/{len(files)}] analysing {path}", file=sys.stderr, flush=True)
        info = analyse_song(path)
        if info is None:
            skipped.append(f"{path}: neither ffmpeg nor the project's loader decodes it")
            continue
        if info.seconds < min_seconds or info.name in taken:
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
        "excluded_sets": [str(f) for f in exclude],
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
