"""Fill the audio feature cache for a folder of songs (resumable).

python -m dgsdp.audio.extract --encoder librosa --wavs data/aistpp/wavs --cache data/cache/audio
python -m dgsdp.audio.extract --encoder jukebox --wavs ... --cache ... --set layer=66 --set device=cuda
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from dgsdp.audio import AUDIO_ENCODERS, build_audio_encoder, extract_dataset
from dgsdp.audio.io import AUDIO_SUFFIXES
from dgsdp.errors import DgsdpError


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--encoder", required=True, choices=sorted(AUDIO_ENCODERS))
    parser.add_argument("--wavs", required=True, type=Path, help="folder of audio files (searched recursively)")
    parser.add_argument("--cache", required=True, type=Path, help="feature cache folder")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="encoder constructor argument (value parsed as YAML), e.g. --set device=cuda",
    )
    parser.add_argument("--no-music-id", action="store_true", help="do not read tempo from AIST++ file names")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        kwargs = {}
        for item in args.set:
            key, sep, value = item.partition("=")
            if not sep:
                raise DgsdpError(f"--set expects KEY=VALUE, got '{item}'.")
            kwargs[key.strip()] = yaml.safe_load(value)
        if not args.wavs.is_dir():
            raise DgsdpError(f"--wavs {args.wavs} is not a folder.")
        paths = sorted(p for p in args.wavs.rglob("*") if p.suffix.lower() in AUDIO_SUFFIXES)
        if not paths:
            raise DgsdpError(f"No audio files ({', '.join(AUDIO_SUFFIXES)}) under {args.wavs}.")
        encoder = build_audio_encoder(args.encoder, **kwargs)
        summary = extract_dataset(encoder, paths, args.cache, music_id_from_name=not args.no_music_id)
    except DgsdpError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(
        f"{summary.n_songs} songs ({summary.audio_seconds:.0f} s of audio): "
        f"{summary.n_computed} encoded, {summary.n_cached} already cached in {args.cache}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
