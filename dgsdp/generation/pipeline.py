"""From a checkpoint, songs and a style to dance files: the generation pipeline behind ``python generate.py``.

:class:`DanceGenerator` holds a trained model with the audio encoder and style embedder it was trained with; it
turns a song into music features, a style string (genre, free text or schedule) into style vectors, an editing
task into a mask and known motion, and samples whole songs with long-form generation. :func:`write_motion`
writes one motion as an AIST++ pickle, a BVH, a video and the raw pose vectors.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dgsdp.audio import AudioEncoder, FeatureCache, audio_duration_seconds
from dgsdp.audio.tempo import TempoFold, beats_tempo_bpm, fold_beats, fold_octaves
from dgsdp.editing import build_mask, check_task, load_motion_file, place_known
from dgsdp.errors import AudioError, ConfigError
from dgsdp.generation.beatsync import BeatSync, other_tracker_beats, song_beats, sync_to_beats
from dgsdp.generation.dance import Dance
from dgsdp.generation.longform import DanceRequest, WindowLayout, sample_items
from dgsdp.generation.schedule import is_schedule, parse_schedule, schedule_styles
from dgsdp.motion import FloorCleanup, Skeleton, clean_motion
from dgsdp.resources import home
from dgsdp.sampling import SamplingSettings
from dgsdp.style.embeddings import SHIPPED_PROMPTS_DIR, load_prompts, resolve_prompts_file
from dgsdp.style.reading import TextReading, TextRouter
from dgsdp.style.vocab import split_free_text
from dgsdp.trained import TrainedModel, load_model
from dgsdp.utils.device import check_cpu_bf16, resolve_device

log = logging.getLogger(__name__)


@dataclass
class EditSettings:
    """An editing task (see :mod:`dgsdp.editing.masks`) and its inputs; ``motion`` is the given motion."""

    task: str = "none"
    motion: torch.Tensor | None = None
    motion_file: str | None = None  # read (at the model's frame rate) when ``motion`` is not given
    seed_frames: int = 30
    end_frames: int = 30
    inpaint_fraction: float = 0.7
    joints: Sequence[int | str] | None = None
    with_root: bool = False
    keyframes: Sequence[int] | None = None
    keyframe_seconds: Sequence[float] | None = None


@dataclass(frozen=True)
class Finishing:
    """The finishing's limits (generate.py's ``finishing`` keys, the studio's options): a model trained on real
    spins, flips and long jumps lifts them (None). ``floor()`` and ``beat_sync()`` give the full settings of
    :func:`dgsdp.motion.clean_motion` and :func:`dgsdp.generation.beatsync.sync_to_beats`."""

    max_turn_rate: float | None = FloorCleanup.max_turn_rate  # rad/s the body's facing may turn
    max_tilt_rate: float | None = FloorCleanup.max_tilt_rate  # rad/s the body's up axis may tilt
    max_air_seconds: float | None = FloorCleanup.max_air_seconds  # longest run without foot contact kept as a jump
    beat_sync_reach: float = BeatSync.max_shift_beats  # how far (in beats) a pause may move to fall on a beat

    def __post_init__(self) -> None:
        for make in (self.floor, self.beat_sync):  # one clear error for a bad value, before any work
            try:
                make()
            except (TypeError, ValueError) as e:
                raise ConfigError(f"finishing: {e} (docs/floor.md, docs/beatsync.md)") from None

    def floor(self) -> FloorCleanup:
        return FloorCleanup(
            max_turn_rate=self.max_turn_rate, max_tilt_rate=self.max_tilt_rate, max_air_seconds=self.max_air_seconds
        )

    def beat_sync(self) -> BeatSync:
        return BeatSync(max_shift_beats=self.beat_sync_reach)


@dataclass
class StylePlan:
    """A resolved style: one vector (ds,), a schedule (spans, embedded per song length), or none; ``readings``:
    how its text (each span's) was read."""

    text: str | None
    vector: torch.Tensor | None = None
    spans: list[Any] | None = None
    readings: list[TextReading] = dataclasses.field(default_factory=list)


def _ranked(names: Sequence[str], weights: np.ndarray) -> tuple[tuple[str, float], ...]:
    """(name, weight) of each genre with some weight, largest first."""
    order = np.argsort(-np.asarray(weights), kind="stable")
    return tuple((names[i], float(weights[i])) for i in order if weights[i] > 1e-4)


def reading_weights(vector: torch.Tensor, bank: torch.Tensor, temperature: float) -> torch.Tensor:
    """(P,) the softmax over ``temperature`` of the cosine similarity of each description (``bank``, P x ds) to a
    free-text style vector (ds,)."""
    return torch.softmax(torch.nn.functional.cosine_similarity(bank, vector[None, :], dim=-1) / temperature, dim=0)


def read_through_bank(
    vector: torch.Tensor, bank: torch.Tensor, temperature: float, values: torch.Tensor | None = None
) -> torch.Tensor:
    """A free-text style vector (ds,) read through the descriptions it resembles: the mean of ``values`` (P, ds;
    default the descriptions' own embeddings ``bank``) weighted by :func:`reading_weights`. A model has only learnt
    what its training descriptions' embeddings ask for; text unlike any of them lies where it has learnt nothing, and
    this keeps it among them (small temperature: the nearest description). With other descriptions than the model's
    own, ``values`` are the model's mean style of each description's genre, so the text asks for a blend of the
    genres it reads as."""
    return reading_weights(vector, bank, temperature) @ (bank if values is None else values)


TEXT_READING_OFF = "off"  # style_text_reading=off (or style_text_temperature=off): free text by its own embedding
TEXT_READINGS = ("router", "blend", TEXT_READING_OFF)


@dataclass(frozen=True)
class TextReadingChoice:
    """How free text is read (docs/style.md): ``how`` "router" (one genre and a speed, :mod:`dgsdp.style.reading`),
    "blend" (the genres of the descriptions it resembles, softmax of the similarity over ``temperature``) or "off"
    (its own embedding); ``descriptions``: the descriptions it is read through (a prompts file or a shipped one's
    name; None: the run's own)."""

    how: str = TEXT_READING_OFF
    temperature: float | None = None
    descriptions: str | None = None

    @classmethod
    def make(cls, how: str | None, temperature: Any = None, descriptions: str | None = None) -> TextReadingChoice:
        """A checked choice; ``how`` None: "blend" when a temperature is given, else "off"."""
        if temperature is not None and str(temperature).strip().lower() == TEXT_READING_OFF:
            how, temperature = how or TEXT_READING_OFF, None
        how = (
            str(how).strip().lower() if how is not None else ("blend" if temperature is not None else TEXT_READING_OFF)
        )
        if how not in TEXT_READINGS:
            raise ConfigError(f"style_text_reading must be one of {', '.join(TEXT_READINGS)} or null, got {how!r}")
        if how == "blend":
            try:
                temperature = float(temperature) if temperature is not None else math.nan
            except (TypeError, ValueError):
                temperature = math.nan
            if not temperature > 0:
                raise ConfigError(
                    "style_text_reading=blend needs style_text_temperature=<a positive number> (0.02 measured best "
                    "with aistpp_augmented, docs/style.md)"
                )
        elif temperature is not None:
            raise ConfigError(f"style_text_temperature is the blend's; style_text_reading={how} takes none")
        if descriptions is not None and how == TEXT_READING_OFF:
            raise ConfigError(
                "style_text_descriptions reads free text through descriptions: set style_text_reading=router (or "
                "style_text_temperature for the blend) too"
            )
        return cls(how, temperature if how == "blend" else None, descriptions)


def recorded_text_reading(record: Mapping[str, Any] | None) -> TextReadingChoice | None:
    """How a run chose to read free text (its config's ``generation.style_text_reading``,
    ``style_text_temperature`` and ``style_text_descriptions``; the style recipes set them), as data, with the
    descriptions only a *shipped* file's name; None where the run chose nothing (older checkpoints, the papers' rows)."""
    chosen = (record or {}).get("generation") or {}
    how, temperature = chosen.get("style_text_reading"), chosen.get("style_text_temperature")
    descriptions = chosen.get("style_text_descriptions")
    if how is None and temperature is None:
        return None
    if temperature is not None and not isinstance(temperature, int | float):
        try:
            temperature = float(temperature)
        except (TypeError, ValueError):
            temperature = math.nan
    if temperature is not None and not temperature > 0:
        raise ConfigError(
            f"the checkpoint's generation.style_text_temperature is {chosen.get('style_text_temperature')!r}, not a "
            "positive number; give style_text_temperature=<number> or style_text_reading=off"
        )
    if descriptions is not None:
        shipped = resolve_prompts_file(str(descriptions))
        if shipped.parent != SHIPPED_PROMPTS_DIR or Path(str(descriptions)).parent != Path("."):
            raise ConfigError(
                f"the checkpoint names the descriptions {descriptions!r} to read free text through, which is not a "
                "shipped file's name; give style_text_descriptions=<your file> or style_text_reading=off"
            )
        descriptions = shipped.stem
    try:
        return TextReadingChoice.make(how, temperature, descriptions)
    except ConfigError as e:
        raise ConfigError(f"the checkpoint's generation settings: {e}") from None


class DanceGenerator:
    """A trained model with its audio encoder and style embedder, ready to dance to whole songs.

    This is the project's one way to sample dances: generate.py, evaluate.py, the training callbacks, the
    benchmarks and the studio all call :meth:`generate_many` (or :meth:`generate` for one dance)."""

    def __init__(
        self,
        model: TrainedModel,
        *,
        cache_dir: str | os.PathLike,
        device: torch.device | str = "cpu",
        max_song_seconds: float | None = None,
        trusted: bool = False,
        text_reading: str | None = None,
        text_temperature: float | str | None = None,
        text_descriptions: str | os.PathLike | None = None,
    ) -> None:
        self.model = model.to(device).eval()
        self.device = torch.device(device)
        self.spec = model.spec
        # parts rebuilt from a checkpoint's config are the project's registered classes only
        self.source = "config" if trusted else "checkpoint"
        self.fps = self.spec.fps
        self.window = self.spec.window_frames
        self.cache = FeatureCache(cache_dir)
        self.cache_dir = Path(cache_dir)
        self.max_song_seconds = max_song_seconds
        self._audio: AudioEncoder | None = None
        self._embedder: Any = None
        self._warned_tempo = False
        given = (text_reading, text_temperature, text_descriptions)
        if all(v is None for v in given):  # what the run chose (the style recipes record it)
            choice = recorded_text_reading(self.spec.record) or TextReadingChoice()
        else:
            choice = TextReadingChoice.make(text_reading, text_temperature, None if text_descriptions is None
                                            else str(text_descriptions))  # fmt: skip
        self.text_choice = choice  # how free text is read (see read_style)
        self._reading: tuple[torch.Tensor, torch.Tensor] | None = None
        self._router: Any = None

    @classmethod
    def from_checkpoint(
        cls,
        path: str | os.PathLike,
        *,
        cache_dir: str | os.PathLike | None = None,
        device: str = "cpu",
        max_song_seconds: float | None = None,
        text_reading: str | None = None,
        text_temperature: float | str | None = None,
        text_descriptions: str | os.PathLike | None = None,
    ) -> DanceGenerator:
        """The model of a checkpoint written by train.py (or the EDGE import), read as data. ``cache_dir``: where
        music features are cached (default: ``data/cache`` of the working folder, as the command-line tools)."""
        if cache_dir is None:
            cache_dir = home() / "data" / "cache"
        return cls(
            load_model(str(path)),
            cache_dir=cache_dir,
            device=resolve_device(device),
            max_song_seconds=max_song_seconds,
            text_reading=text_reading,
            text_temperature=text_temperature,
            text_descriptions=text_descriptions,
        )

    @property
    def skeleton(self) -> Skeleton:
        """The skeleton of the run's motion (pose vectors of ``skeleton.pose_dim`` channels)."""
        return self.model.skeleton

    @property
    def floor_height(self) -> float:
        """The floor of the run's training data (z-up metres; 0.0 for checkpoints from before it was stored)."""
        return float(self.model.floor_height)

    # --- conditioning ---------------------------------------------------------------------------------------
    @property
    def audio_encoder(self) -> AudioEncoder | None:
        """The run's audio encoder (built on first use), or None for a model without music."""
        if self._audio is None and self.spec.conditioning.audio_dim:
            self._audio = self.spec.build_audio_encoder(self.source)
        return self._audio

    def check_duration(self, path: Path) -> float:
        """The song's length in seconds; AudioError past ``max_song_seconds``."""
        seconds = audio_duration_seconds(path)
        if self.max_song_seconds is not None and seconds > self.max_song_seconds:
            raise AudioError(
                f"{path.name} is {seconds:.0f} s long; the limit is max_song_seconds={self.max_song_seconds:g} "
                "(raise it for longer songs: time and memory grow linearly with length, or set seconds=... "
                "to dance to the start of the song only)"
            )
        return seconds

    def window_layout(self, sampling: SamplingSettings | None = None) -> tuple[int, int]:
        """The long-form window and stride (frames) that ``sampling`` gives this model."""
        sampling = sampling or SamplingSettings()
        window = min(sampling.window_frames or self.window, self.model.denoiser.seq_len)
        return window, sampling.stride(window)

    def music_features(
        self, path: Path, seconds: float | None = None, sampling: SamplingSettings | None = None
    ) -> tuple[torch.Tensor | None, int]:
        """Music features (T, Da) at 30 FPS of the whole song (or its first ``seconds``), and T. An encoder with
        ``per_window`` (EDGE's procedure) gives each long-form window of ``sampling`` its own features instead:
        (n_windows, window, Da), each computed from the window's own audio. A song far outside the model's training
        tempi has its beats folded (:meth:`tempo_fold`)."""
        music, n_frames, _ = self._song_music(path, seconds, sampling)
        return music, n_frames

    def tempo_fold(self, path: Path, sampling: SamplingSettings | None = None) -> TempoFold:
        """How :meth:`music_features` gives the model the beats of a song with ``sampling`` (its ``tempo_fold``): the
        song's tempo and the octaves it is folded by toward the model's training tempi."""
        return self._song_music(Path(path), None, sampling)[2]

    def training_tempi(self, sampling: SamplingSettings | None = None) -> tuple[tuple[float, float] | None, str]:
        """The tempo range songs are folded toward with ``sampling``, and where it comes from
        (``sampling.tempo_range_bpm`` or ``checkpoint``); (None, why) when folding is off or no range is known."""
        sampling = sampling or SamplingSettings()
        if not sampling.tempo_fold:
            return None, "off"
        if sampling.tempo_range_bpm:
            lo, hi = sampling.tempo_range_bpm
            return (lo, hi), "sampling.tempo_range_bpm"
        known = self.model.tempo_range
        return (known, "checkpoint") if known is not None else (None, "no training tempi recorded")

    def _song_music(
        self, path: Path, seconds: float | None, sampling: SamplingSettings | None
    ) -> tuple[torch.Tensor | None, int, TempoFold]:
        """:meth:`music_features` and :meth:`tempo_fold` at once (the song's features are read once)."""
        duration = self.check_duration(path)
        limit = None if seconds is None else int(round(seconds * self.fps))
        short = AudioError(f"{path.name} is shorter than one motion frame ({1 / self.fps:.3f} s)")
        if self.audio_encoder is None or self.audio_encoder.per_window:
            n = int(duration * self.fps) if limit is None else min(int(duration * self.fps), limit)
            if n < 1:
                raise short
            return (None if self.audio_encoder is None else self.music_windows(path, 0, n, sampling)), n, TempoFold()
        feats = self.cache.features_for_file(self.audio_encoder, path, music_id=path.stem)
        beats = self.audio_encoder.feature_beats(feats)
        fold = TempoFold()
        if beats is not None:
            bpm = beats_tempo_bpm(beats, self.fps)
            tempo_range, source = self.training_tempi(sampling)
            if tempo_range is None and source != "off" and not self._warned_tempo:
                log.warning(
                    "this checkpoint records no training tempi, so songs far faster or slower than its training music "
                    "are not folded to half or double time: give sampling.tempo_range_bpm=[lowest,highest] (or "
                    "retrain: train.py records them)"
                )
                self._warned_tempo = True
            fold = TempoFold(bpm, *((fold_octaves(bpm, tempo_range), tempo_range) if tempo_range else ()))
        if fold.octaves:
            strength = self.audio_encoder.beat_strength(feats)
            feats = self.audio_encoder.with_beats(feats, fold_beats(beats, fold.octaves, strength))
        if limit is not None:
            feats = feats[:limit]
        if len(feats) < 1:
            raise short
        return torch.from_numpy(np.array(feats)), len(feats), fold  # a copy: the cached array is read-only

    def music_windows(
        self,
        path: Path,
        start_frame: int,
        n_frames: int,
        sampling: SamplingSettings | None = None,
        music_id: str | None = None,
    ) -> torch.Tensor:
        """Features (n_windows, window, Da) of the long-form windows of ``sampling`` over frames
        ``start_frame .. start_frame + n_frames`` of a song, each computed from its own audio (encoders with
        ``per_window``: EDGE's procedure); cached."""
        if self.audio_encoder is None:
            raise ConfigError("this model has no music input")
        window, stride = self.window_layout(sampling)
        starts = [start_frame + s for s in WindowLayout(n_frames, window, stride).starts()]
        music_id = path.stem if music_id is None else music_id
        windows = self.cache.windows_for_file(self.audio_encoder, path, starts, window, music_id=music_id)
        return torch.from_numpy(np.array(windows))

    @property
    def style_dim(self) -> int:
        """The size of the model's style vector (0 for a model without style)."""
        return int(self.model.style_dim)

    def embedder(self) -> Any:
        """The StyleEmbedder of the run (its text encoder loads only for free text)."""
        if self._embedder is None:
            if not self.spec.style:
                raise ConfigError("the checkpoint's run has no style config; it cannot embed style text")
            self._embedder = self.spec.build_style_embedder(self.source, cache_dir=str(self.cache_dir))
        return self._embedder

    def embed_style(self, text: str) -> torch.Tensor:
        """Style vector (ds,) of a genre (code or name, from the checkpoint's bank) or free text (read as
        :attr:`text_choice` says); (ds + C,) with the movement channels of a model conditioned on them."""
        return self.read_style(text)[0]

    def read_style(self, text: str) -> tuple[torch.Tensor, TextReading]:
        """The style vector of :meth:`embed_style` and how the text was read (:class:`TextReading`)."""
        embedder = self.embedder()
        bank = self.model.style_bank
        names = embedder.vocab.names
        if bank is not None and text in embedder.vocab:
            g = embedder.vocab.index(text)
            vector = self._genre_means(bank)[g]
            return self._with_movement(vector, TextReading(text, "genre", genre=names[g]), genre=g)
        vector = embedder.embed_text(text).float().cpu()  # checks the text (one-hot models take genres only)
        how = self.text_choice.how
        if bank is None or len(bank) < 2 or embedder.kind != "prompt" or how == TEXT_READING_OFF:
            return self._with_movement(vector, TextReading(text, "own"))
        clean = " ".join(split_free_text(text)[0].split())
        if how == "blend":
            keys, values = self._text_reading(embedder, bank)
            weights = reading_weights(vector, keys, self.text_choice.temperature)
            vector = read_through_bank(vector, keys, self.text_choice.temperature, values)
            genres = self._reading_genres(embedder, bank)
            per_genre = torch.zeros(len(names)).index_add_(0, genres, weights)
            reading = TextReading(clean, "blend", weights=_ranked(names, per_genre.numpy()))
            return self._with_movement(vector, reading, weights=per_genre)
        probs, energy, known, closest, similarity = self.router().read(clean)
        attributes = tuple(self.router().read_attributes(clean).items())
        means = self._genre_means(bank)
        if known:
            g = int(np.argmax(probs))
            excluded = tuple(names[i] for i in self.router().negated_genres(clean))
            reading = TextReading(clean, "router", _ranked(names, probs), names[g], energy, True, closest, similarity,
                                  excluded=excluded, attributes=attributes)  # fmt: skip
            return self._with_movement(means[g], reading, genre=g)
        # no particular genre: the mean of the bank's genres but those the text negates, at the energy's pace
        excluded = self.router().negated_genres(clean)
        in_bank = [i for i in range(len(names)) if bool((bank.genre_index == i).any())]
        present = [i for i in in_bank if i not in excluded] or in_bank
        weights = torch.zeros(len(names)).index_fill_(0, torch.tensor(present), 1.0)
        reading = TextReading(clean, "router", _ranked(names, probs), None, energy, False, closest, similarity,
                              excluded=tuple(names[i] for i in excluded), attributes=attributes)  # fmt: skip
        return self._with_movement(means[present].mean(0), reading, weights=weights)

    def _genre_means(self, bank: Any) -> torch.Tensor:
        """(n_genres, ds): each genre's mean style vector (zeros for a genre the bank lacks)."""
        out = torch.zeros(len(self.embedder().vocab), bank.vectors.shape[-1])
        for g in range(len(out)):
            if bool((bank.genre_index == g).any()):
                out[g] = bank.mean_for(torch.tensor([g], device=bank.vectors.device))[0].float().cpu()
        return out

    def _with_movement(
        self,
        vector: torch.Tensor,
        reading: TextReading,
        *,
        genre: int | None = None,
        weights: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TextReading]:
        """The style vector with the movement channels a model conditioned on them takes, and the reading with the
        values asked (:meth:`~dgsdp.trained.TrainedModel.asked_movement`: each channel at the quantile the reading
        asks, the speed by its energy, another attribute by its score and at least ``ATTRIBUTE_REACH`` of all
        windows' spread from the median; the median when it says nothing) of a genre's training windows, of the
        ``weights``' blend of the genres', or else the training windows' medians; other models: unchanged."""
        model = self.model
        channels = getattr(model, "movement_channels", ())
        if not channels:
            return vector, reading
        scores = {"speed": reading.energy, **dict(reading.attributes)}
        asked = torch.tensor([scores.get(name, 0.0) for name in channels])
        if genre is not None:
            values = model.asked_movement(torch.tensor([genre]), asked)[0]
        elif weights is not None:
            table = model.asked_movement(torch.arange(len(weights)), asked)
            values = (weights.to(table) @ table) / weights.sum().clamp_min(1e-12)
        else:
            values = torch.stack([getattr(model, f"{name}_reference").float() for name in channels])
        values = values.float().cpu()
        asked = dict(zip(channels, (float(v) for v in values), strict=True))
        reading = dataclasses.replace(
            reading, speed_m_s=asked.pop("speed", None), movement=tuple((k, v) for k, v in asked.items())
        )
        return model.with_movement(vector.float(), values).cpu(), reading

    def router(self) -> TextRouter:
        """The free-text reader of ``style_text_reading=router``, fitted once on the descriptions read through (the
        run's own training descriptions unless ``style_text_descriptions`` names others)."""
        if self._router is None:
            embedder = self.embedder()
            path = self.text_choice.descriptions or embedder.prompts_file
            per_genre = load_prompts(resolve_prompts_file(path), embedder.vocab)
            names = [n.lower() for n in embedder.vocab.names]
            # the movement attributes this model takes (model.movement_channels): no other is read or reported
            channels = getattr(self.model, "movement_channels", ())
            self._router = TextRouter(
                per_genre, embedder.embed_texts, names, movement=[c for c in channels if c != "speed"]
            )
        return self._router

    def _reading_genres(self, embedder: Any, bank: Any) -> torch.Tensor:
        """The genre of each description the blend reads through (P,)."""
        if self.text_choice.descriptions is None:
            return bank.genre_index.cpu()
        per_genre = load_prompts(resolve_prompts_file(self.text_choice.descriptions), embedder.vocab)
        return torch.tensor([g for g, texts in enumerate(per_genre) for _ in texts])

    def _text_reading(self, embedder: Any, bank: Any) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The descriptions free text is read through (P, ds) and what each stands for (None: itself)."""
        if self.text_choice.descriptions is None:
            return bank.vectors.float().cpu(), None
        if self._reading is None:
            per_genre = load_prompts(resolve_prompts_file(self.text_choice.descriptions), embedder.vocab)
            keys = embedder.embed_texts([t for texts in per_genre for t in texts]).float().cpu()
            genres = torch.tensor([g for g, texts in enumerate(per_genre) for _ in texts], device=bank.vectors.device)
            self._reading = (keys, bank.mean_for(genres).float().cpu())
        return self._reading

    def resolve_style(self, style: str | None) -> StylePlan:
        """Check and embed a style string once (before any song): genre, free text or schedule."""
        text = None if style is None else str(style).strip()
        if not text or text.lower() in ("none", "null"):
            if self.style_dim:
                vocab = self.embedder().vocab
                raise ConfigError(
                    "this model is conditioned on style: give style=<genre, description or schedule>; "
                    f"genres: {vocab.describe()}"
                )
            return StylePlan(None)
        if not self.style_dim:
            raise ConfigError(f"this model was trained without style conditioning (style=none); drop style={text!r}")
        if is_schedule(text):
            spans = parse_schedule(text)
            readings = [self.read_style(span.style)[1] for span in spans]  # fails early on an unknown genre
            return StylePlan(text, spans=spans, readings=readings)
        vector, reading = self.read_style(text)
        return StylePlan(text, vector=vector, readings=[reading])

    def style_frames(self, plan: StylePlan, n_frames: int, blend_seconds: float) -> torch.Tensor | None:
        """(ds,) for one style, (n_frames, ds) for a schedule, None without style."""
        if plan.spans is not None:
            return schedule_styles(plan.spans, n_frames, self.embed_style, fps=self.fps, blend_seconds=blend_seconds)
        return plan.vector

    # --- editing --------------------------------------------------------------------------------------------
    def edit_inputs(
        self, edit: EditSettings, n_frames: int, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """(mask, known), both (n_frames, D) (the run's pose size), or (None, None) without a task."""
        task = check_task(edit.task)
        if task == "none":
            return None, None
        if edit.motion is None and edit.motion_file:
            motion = load_motion_file(edit.motion_file, fps=self.fps, skeleton=self.skeleton)
            edit = dataclasses.replace(edit, motion=motion)
        if edit.motion is None:
            raise ConfigError(
                f"task={task} needs the given motion: set seed_motion_file (seed_motion, inbetween), "
                "keyframes_file (keyframes) or motion_file (any task)"
            )
        mask = build_mask(
            task,
            n_frames,
            seed_frames=edit.seed_frames,
            end_frames=edit.end_frames,
            inpaint_fraction=edit.inpaint_fraction,
            joints=edit.joints,
            with_root=edit.with_root,
            keyframes=edit.keyframes,
            keyframe_seconds=edit.keyframe_seconds,
            fps=self.fps,
            generator=generator,
            skeleton=self.skeleton,
        )
        known = place_known(task, edit.motion, mask, seed_frames=edit.seed_frames, end_frames=edit.end_frames)
        return mask, known

    # --- sampling -------------------------------------------------------------------------------------------
    def generate_many(
        self, requests: Sequence[DanceRequest], sampling: SamplingSettings | None = None, *, progress: bool = False
    ) -> list[torch.Tensor]:
        """Unnormalised motions (num_samples, n_frames, D) (D: the run's pose size), one per request, sampled in
        batches of up to ``sampling.batch_size`` requests of the same length and editing state. A request's result
        depends only on the request and its seed, not on the batch it was sampled in."""
        sampling = sampling or SamplingSettings()
        window, stride = self.window_layout(sampling)
        groups: dict[tuple[int, bool], list[int]] = {}
        for i, r in enumerate(requests):
            if r.n_frames < 1:
                raise ConfigError(f"a dance needs at least one frame, got {r.n_frames}")
            groups.setdefault((r.n_frames, r.mask is not None), []).append(i)
        batches = [
            idx[k : k + sampling.batch_size] for idx in groups.values() for k in range(0, len(idx), sampling.batch_size)
        ]
        out: list[torch.Tensor | None] = [None] * len(requests)
        self._check_student_weights(sampling)
        if sampling.bf16 and self.device.type == "cpu":
            check_cpu_bf16("sampling.bf16=true")
        autocast = torch.autocast(self.device.type, dtype=torch.bfloat16) if sampling.bf16 else contextlib.nullcontext()
        for batch in batches:
            items = [requests[i] for i in batch]
            guidance = sampling.guidance_for(long=requests[batch[0]].n_frames > window)
            with autocast:
                motions = sample_items(
                    self.model.sampler(), self.model.normalizer, items, window=window, stride=stride,
                    method=sampling.method, steps=sampling.steps, eta=sampling.eta, guidance=guidance,
                    chunk_size=sampling.chunk_size, longform=sampling.longform, clip_x0=sampling.clip_x0,
                    project=sampling.project_rotations, align_facing=sampling.align_facing,
                    device=self.device, progress=progress, skeleton=self.skeleton,
                )  # fmt: skip
            for i, motion in zip(batch, motions):
                out[i] = motion.float().cpu()
        return out  # type: ignore[return-value]

    def _check_student_weights(self, sampling: SamplingSettings) -> None:
        """A guidance-distilled student learnt weights up to its ``distill.max_weight``: warn above it."""
        if not getattr(self.model.ema.module, "guidance_inputs", 0):
            return
        trained = (self.spec.record.get("distill") or {}).get("max_weight")
        weights = (sampling.guidance.music, sampling.guidance.style)[: self.model.ema.module.guidance_inputs]
        if isinstance(trained, int | float) and max(weights) > trained:
            log.warning(
                "this guidance-distilled student learnt guidance weights up to %g; %g is beyond them (it extrapolates): "
                "retrain it with a larger distill.max_weight or sample with a smaller weight", trained, max(weights),
            )  # fmt: skip

    def dance_to_song(
        self,
        song: str | os.PathLike,
        style: str | StylePlan | None = None,
        *,
        edit: EditSettings | None = None,
        seconds: float | None = None,
        blend_seconds: float = 2.0,
        num_samples: int = 1,
        sampling: SamplingSettings | None = None,
        seed: int | None = 0,
        progress: bool = False,
        cleanup: bool | FloorCleanup = True,
        beat_sync: bool | BeatSync = True,
    ) -> Dance:
        """Dances to a whole song (or its first ``seconds``) in a style (a genre, a free-text description, a
        schedule, or a :class:`StylePlan` from :meth:`resolve_style`; None for models without style), with an
        optional editing task: music features, style per frame, editing mask, then :meth:`generate`, then
        :meth:`finish` (``cleanup`` and ``beat_sync``)."""
        song = Path(song)
        plan = style if isinstance(style, StylePlan) else self.resolve_style(style)
        music, n_frames, tempo = self._song_music(song, seconds, sampling)
        style = self.style_frames(plan, n_frames, blend_seconds)
        mask, known = self.edit_inputs(edit or EditSettings(), n_frames)
        motions = self.generate(
            n_frames, music=music, style=style, mask=mask, known=known, num_samples=num_samples,
            sampling=sampling, seed=seed, progress=progress,
        )  # fmt: skip
        retime = cleanup is not False and beat_sync is not False and mask is None and music is not None
        beats = song_beats(song, self.cache, self.audio_encoder) if retime else None
        # the retime is judged by another tracker's beats too, which it did not align to
        check = [other_tracker_beats(song, self.cache, self.audio_encoder).frames] if retime else []
        stats: list[dict[str, float]] = []
        finished = self.finish(
            motions, beats, mask=mask, cleanup=cleanup, beat_sync=beat_sync, stats=stats, check_beats=check
        )
        return Dance(
            finished, self.fps, self.floor_height, song, plan.text, raw=motions, finishing=stats, tempo=tempo,
            skeleton=self.skeleton, readings=plan.readings,
        )  # fmt: skip

    def finish(
        self,
        motions: torch.Tensor,
        music_beats: np.ndarray | None,
        *,
        mask: torch.Tensor | None = None,
        cleanup: bool | FloorCleanup = True,
        beat_sync: bool | BeatSync = True,
        stats: list[dict[str, float]] | None = None,
        check_beats: list[np.ndarray] | tuple[np.ndarray, ...] = (),
    ) -> torch.Tensor:
        """The model's dances (S, T, D) as generate.py writes them. ``cleanup`` False: unchanged (the model's raw
        output). Otherwise the feet are put on the run's floor (:func:`dgsdp.motion.clean_motion`; given channels of an
        edit are kept exactly), and, unless ``beat_sync`` is False, each dance is first retimed so that its pauses fall
        on the music beats (frames, (K,); :func:`dgsdp.generation.beatsync.sync_to_beats`; not with an editing
        ``mask``, whose given frames would move, nor without beats). The judge decides on the finished dances: the
        retime is kept where the finished dance is no worse on those beats and on each of ``check_beats`` (another
        tracker's beat frames) than the same dance finished in the model's own timing (and than the raw dance where
        the cleanup alone lowered that; the floor cleanup runs at most twice per dance). ``stats``: a list that gets
        one dict per dance of what each step changed (the ``stats`` of both functions; empty for a step not run)."""
        if cleanup is False:
            if stats is not None:
                stats.extend({} for _ in range(motions.shape[0] if motions.ndim == 3 else 1))
            return motions
        floor = cleanup if isinstance(cleanup, FloorCleanup) else None

        def clean(x: torch.Tensor, cleaned: list[dict[str, float]]) -> torch.Tensor:
            return clean_motion(
                x, self.fps, self.floor_height, mask=mask, settings=floor, stats=cleaned, skeleton=self.skeleton
            )

        notes: list[dict[str, float]] = []
        if beat_sync is not False and music_beats is not None:
            settings = beat_sync if isinstance(beat_sync, BeatSync) else None
            beats = np.asarray(music_beats)
            motions = sync_to_beats(
                motions, beats[beats < motions.shape[-2]], self.fps, mask=mask, settings=settings, stats=notes,
                skeleton=self.skeleton, check_beats=[np.asarray(b) for b in check_beats], finish=clean,
            )  # fmt: skip
        else:
            motions = clean(motions, notes)
        if stats is not None:
            stats.extend(notes)
        return motions

    def generate(
        self,
        n_frames: int,
        *,
        music: torch.Tensor | None = None,
        style: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        known: torch.Tensor | None = None,
        num_samples: int = 1,
        sampling: SamplingSettings | None = None,
        seed: int | None = 0,
        progress: bool = False,
    ) -> torch.Tensor:
        """Unnormalised motions (num_samples, n_frames, D); music (n_frames, Da), style (ds,)/(n_frames, ds)."""
        request = DanceRequest(n_frames, music, style, mask, known, num_samples, seed)
        return self.generate_many([request], sampling, progress=progress)[0]
