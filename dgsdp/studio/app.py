"""The studio page (Gradio): upload a song, choose a style and a model, generate, watch, edit, download.

Everything is served from this machine: the theme uses system fonts, analytics are off, and the 3D viewer is
plain JavaScript (:mod:`dgsdp.studio.viewer`). Each generation writes into its own folder under the studio's
work folder, and each browser session keeps its own current dance, so users sharing a studio never see each
other's results; with logins, each login's dances and uploads can be read by that login only
(:mod:`dgsdp.studio.access`). The model runs one request at a time from a queue.
"""

from __future__ import annotations

import argparse
import contextlib
import html
import logging
import math
import os
import re
import shutil
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("GRADIO_ANALYTICS_ENABLED", "False")

import gradio as gr  # noqa: E402
import numpy as np  # noqa: E402
import soundfile as sf  # noqa: E402

from dgsdp.errors import AudioError, ConfigError, DgsdpError  # noqa: E402
from dgsdp.generation import Finishing, parse_schedule  # noqa: E402
from dgsdp.sampling import METHODS, GuidanceSettings, SamplingSettings  # noqa: E402
from dgsdp.studio import engine as eng  # noqa: E402
from dgsdp.studio.access import LOGIN_PREFIX, FileAccess, LoginFiles  # noqa: E402
from dgsdp.studio.viewer import CSS_TEMPLATE, HTML_TEMPLATE, JS_ON_LOAD, viewer_value, write_joints_json  # noqa: E402
from dgsdp.style import AISTPP_GENRES  # noqa: E402
from dgsdp.utils.deadline import time_limit  # noqa: E402

log = logging.getLogger(__name__)

AUDIO_TYPES = (".wav", ".mp3", ".ogg", ".flac")
EDIT_LABELS = {
    "Keep the lower body, regenerate the upper body": "upper_body",
    "Keep the upper body, regenerate the lower body": "lower_body",
    "Keep poses at keyframes (seconds), regenerate the rest": "keyframes",
    "Continue from the current dance (on the song above)": "continue",
    "Regenerate a time range": "range",
}
SCHEDULE_HEADERS = ["start (s)", "end (s, or end)", "style"]
MAX_STYLE_CHARS = 1000  # a style text (free text or one timeline cell); the text encoders read far fewer
MAX_TIMELINE_ROWS = 50
LOOPBACK_HOSTS = ("localhost", "::1")  # and 127.0.0.0/8


@dataclass
class StudioConfig:
    """Command-line settings of the studio."""

    checkpoint: str | None = None
    host: str = "127.0.0.1"
    port: int = 7860
    outputs: str = "outputs"  # runs are searched here: <outputs>/**/checkpoints/last.ckpt
    work_dir: str = "outputs/studio"  # one folder per generation, example songs, feature cache
    max_upload_mb: float = 50.0
    max_song_seconds: float = 300.0
    device: str = "auto"
    queue_size: int = 16
    default_steps: int = SamplingSettings.steps
    finishing: Finishing = field(default_factory=Finishing)  # the finishing's limits (generate.py's finishing keys)
    allow_checkpoint_paths: bool = False  # True: the model box also opens typed paths of .ckpt files
    request_timeout_s: float = 600.0  # each request is stopped after this long, and the queue moves on
    keep_runs: int = 50  # newest run folders (and song uploads) kept; 0 keeps them all
    auth: list[tuple[str, str]] = field(default_factory=list)  # logins (user, password); empty: no login


def find_checkpoints(outputs: str | Path) -> list[str]:
    """``last.ckpt`` of every run under ``outputs``, newest first."""
    root = Path(outputs)
    if not root.is_dir():
        return []
    found = [p for p in root.glob("**/checkpoints/last.ckpt") if p.is_file()]
    return [str(p) for p in sorted(found, key=lambda p: p.stat().st_mtime, reverse=True)]


def schedule_text(rows: Any) -> str:
    """The schedule string ``'a-b: style; ...'`` of timeline rows (start, end, style); '' for no rows.

    Empty rows are skipped; ``end`` may be blank or ``end`` (the end of the song). ConfigError for a bad row.
    """
    if rows is None:
        return ""
    if hasattr(rows, "values") and hasattr(rows, "columns"):  # a pandas DataFrame
        rows = rows.values.tolist()
    parts = []
    rows = [row for row in rows if any(_cell(c) for c in list(row)[:3])]
    if len(rows) > MAX_TIMELINE_ROWS:
        raise ConfigError(f"the timeline has {len(rows)} rows; give at most {MAX_TIMELINE_ROWS} spans")
    for row in rows:
        cells = [_cell(c) for c in list(row)[:3]]
        cells += [""] * (3 - len(cells))
        start, end, style = cells
        if not style:
            raise ConfigError(f"the timeline row {start or '?'}-{end or 'end'} has no style; type a genre or text")
        check_style_length(style, f"the timeline row {start or '0'}-{end or 'end'}'s style")
        try:
            start_s = finite(start or 0, f"the timeline row {start}-{end}'s start")
            end_s = None if end.lower() in ("", "end") else finite(end, f"the timeline row {start}-{end}'s end")
        except ConfigError:
            raise ConfigError(
                f"the timeline row {start}-{end}: times are seconds (finite numbers), the last end may be 'end'"
            ) from None
        if start_s < 0 or (end_s is not None and end_s <= start_s):
            raise ConfigError(f"the timeline row {start}-{end} must start at 0 s or later and end after it starts")
        if '"' in style and "'" in style:
            raise ConfigError(f"the style {style!r} has both kinds of quotes; drop one")
        quote = "'" if '"' in style else '"'
        parts.append(f"{start_s:g}-{'end' if end_s is None else f'{end_s:g}'}: {quote}{style}{quote}")
    return "; ".join(parts)


def _cell(value: Any) -> str:
    """A timeline cell as text ('' for an empty cell)."""
    return "" if value is None or (isinstance(value, float) and np.isnan(value)) else str(value).strip()


def check_style_length(text: str, what: str = "the style") -> None:
    """ConfigError for a style text longer than :data:`MAX_STYLE_CHARS`."""
    if len(text) > MAX_STYLE_CHARS:
        raise ConfigError(f"{what} has {len(text)} characters; the limit is {MAX_STYLE_CHARS}: describe it shorter")


def finite(value: Any, what: str, integer: bool = False) -> float | int:
    """A field's value as a finite number (ConfigError naming the field for text, NaN or infinity)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number):
        raise ConfigError(f"{what} must be a finite number, got {value!r}")
    if integer:
        if number != int(number):
            raise ConfigError(f"{what} must be a whole number, got {value!r}")
        return int(number)
    return number


def style_text(genre: str | None, free_text: str | None, rows: Any) -> str | None:
    """The style to use: the timeline when it has rows, else the free text, else the genre (None: no style)."""
    schedule = schedule_text(rows)
    if schedule:
        return schedule
    for choice in (free_text, genre):
        if choice and str(choice).strip():
            text = str(choice).strip()
            check_style_length(text)
            return text
    return None


SPAN_COLOURS = ("#e8a33d", "#4c8bd6", "#5bb36b", "#c4577a", "#8a6cc9", "#3fb3b0")


def timeline_html(spans: list[Any], song_seconds: float | None) -> str:
    """A bar along the song with one coloured block per span (gaps take the nearest span's style)."""
    finite = [s.end_s for s in spans if math.isfinite(s.end_s)] + [s.start_s for s in spans]
    total = song_seconds or max(finite) * 1.25 or 10.0
    blocks = []
    for i, span in enumerate(spans):
        end = min(span.end_s, total)
        if end <= span.start_s:
            continue
        left, width = 100 * span.start_s / total, 100 * (end - span.start_s) / total
        label = html.escape(f"{span.start_s:g}-{'end' if not math.isfinite(span.end_s) else f'{span.end_s:g}'} s: "
                            f"{span.style}")  # fmt: skip
        blocks.append(
            f'<div title="{label}" style="position:absolute;left:{left:.2f}%;width:{width:.2f}%;top:0;bottom:0;'
            f"background:{SPAN_COLOURS[i % len(SPAN_COLOURS)]};overflow:hidden;white-space:nowrap;font-size:12px;"
            f'color:#fff;padding:3px 4px;box-sizing:border-box;border-right:1px solid #fff">{label}</div>'
        )
    length = f"{total:.1f} s" if song_seconds else "song length unknown: upload the song to see it to scale"
    return (
        '<div class="dgsdp-timeline" style="position:relative;height:24px;background:#e6e8ec;border-radius:4px;'
        f'overflow:hidden">{"".join(blocks)}</div><div style="font-size:12px;color:#667">0 s ... {length}</div>'
    )


def _safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_")[:60] or "song"


class Studio:
    """The page's handlers, with the engine and the folders they share."""

    def __init__(self, config: StudioConfig, engine: eng.Engine | None = None) -> None:
        from gradio.utils import get_upload_folder

        self.config = config
        self.work_dir = Path(config.work_dir).expanduser().resolve()
        self.work_dir.mkdir(parents=True, exist_ok=True)
        self.access = FileAccess(self.work_dir, Path(get_upload_folder()))  # who may read which file (logins)
        self.engine = engine or eng.Engine(
            self.work_dir / "cache", device=config.device, max_song_seconds=config.max_song_seconds,
            finishing=config.finishing,
        )  # fmt: skip

    # --- helpers ----------------------------------------------------------------------------------------------
    def checkpoints(self) -> list[str]:
        """The models the page offers: ``--checkpoint`` first, then the runs under the outputs folder."""
        found = find_checkpoints(self.config.outputs)
        if self.config.checkpoint:
            first = str(Path(self.config.checkpoint).expanduser())
            found = [first] + [c for c in found if Path(c).resolve() != Path(first).resolve()]
        return found

    def checkpoint_path(self, choice: str | None) -> str:
        """The checkpoint of the model box: one the page lists; a typed path only with ``--allow-checkpoint-paths``.

        Without the flag, a path that is not listed gets the same message whether or not it exists, so the page
        tells nobody which files the server has."""
        text = str(choice or "").strip()
        if not text:
            raise ConfigError("choose a model: one of the runs listed in the Model box")
        if text in self.checkpoints():
            return text
        if not self.config.allow_checkpoint_paths:
            raise ConfigError(
                "choose one of the models listed in the Model box; this studio does not open other paths "
                "(whoever runs it can allow typed paths with --allow-checkpoint-paths)"
            )
        path = Path(text).expanduser()
        if path.exists() and not path.is_file():
            raise ConfigError(f"{text} is not a checkpoint file (a folder or a device); give the path of a .ckpt")
        return text

    def login(self, request: gr.Request | None) -> str | None:
        """The login a handler serves ('' for a request without one); None when the studio has no logins, or for a
        call from this process (no request): then every file is everyone's."""
        if not self.config.auth or request is None:
            return None
        return getattr(request, "username", None) or ""

    def run_folders(self) -> list[Path]:
        """Every run folder, newest first: ``runs/<run>`` (no logins) and ``runs/<login folder>/<run>``."""
        runs = self.work_dir / "runs"
        found = []
        for entry in _entries(runs):
            found += _entries(entry) if entry.name.startswith(LOGIN_PREFIX) and entry.is_dir() else [entry]
        return _by_age(found)

    def prune(self) -> None:
        """Keep the newest ``keep_runs`` finished run folders (of all logins together) and song uploads; remove the
        rest, and run folders that never got their viewer file (a request killed mid-way) once they are older than
        a request can be."""
        keep = self.config.keep_runs
        runs = self.run_folders()
        finished = [d for d in runs if (d / "viewer.json").is_file()]
        stale = [d for d in runs if d not in finished and _age_s(d) > self.config.request_timeout_s + 60]
        doomed = stale + (finished[keep:] if keep > 0 else [])
        uploads = self.uploads_dir()
        if uploads is not None and keep > 0:
            doomed += _newest_first(uploads)[keep:]
        for path in doomed:
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
        self.access.forget_removed()

    def uploads_dir(self) -> Path | None:
        """Gradio's upload folder when it is this studio's own (inside its work folder), else None."""
        folder = self.access.upload_dir
        return folder if folder.is_relative_to(self.work_dir) else None

    def request_folder(self, login: str | None = None) -> Path:
        """A fresh run folder in the login's folder of runs (see :meth:`FileAccess.runs_folder`)."""
        folder = self.access.runs_folder(login) / f"{time.strftime('%Y%m%d-%H%M%S')}-{uuid.uuid4().hex[:8]}"
        folder.mkdir(parents=True)
        return folder

    def check_song(self, song: str | None, login: str | None = None) -> Path:
        """The song of a request: an audio file within the upload limit that ``login`` may use (its own upload or
        dance, or an example song); another login's song gets the same message as a missing one."""
        if not song:
            raise AudioError("upload a song (wav, mp3, ogg or flac) or pick an example song first")
        path = Path(song)
        if path.suffix.lower() not in AUDIO_TYPES:
            raise AudioError(f"{path.name} is not a song this studio reads; upload a wav, mp3, ogg or flac file")
        if not path.is_file() or not self.access.may_use(login, path):
            raise AudioError(f"the song {path.name} is no longer on the server; upload it again")
        size_mb = path.stat().st_size / 2**20
        if size_mb > self.config.max_upload_mb:
            raise AudioError(f"{path.name} is {size_mb:.0f} MB; the limit is {self.config.max_upload_mb:g} MB")
        return path

    def example_song(self, genre: str) -> str:
        """A synthetic song in a genre's style (10 s), written once into the work folder."""
        from dgsdp.data.aistpp import music_tempo_bpm
        from dgsdp.data.synthetic_music import synthesize_music, wav_bytes
        from dgsdp.utils.io import atomic_write_bytes

        code = AISTPP_GENRES.codes[AISTPP_GENRES.index(genre)]
        path = self.work_dir / "examples" / f"example_{code}.wav"
        if not path.is_file():
            bpm = music_tempo_bpm(f"m{code}0")
            audio, _ = synthesize_music(
                code, bpm, 10.0, first_beat_s=0.25, sample_rate_hz=22050, rng=np.random.default_rng(0)
            )
            atomic_write_bytes(path, wav_bytes(audio, 22050))
        return str(path)

    # --- handlers ---------------------------------------------------------------------------------------------
    def on_example(self, genre: str | None):
        if not genre:
            return gr.update()
        try:
            return self.example_song(genre)
        except DgsdpError as e:
            raise gr.Error(str(e)) from None

    def on_checkpoint(self, checkpoint: str | None, genre: str | None):
        """Load the chosen model; list its genres (one clear error for a wrong checkpoint)."""
        if not checkpoint:
            return gr.update(), "Choose a model: one of the runs listed in the Model box."
        try:
            genres = self.engine.genres(self.checkpoint_path(checkpoint))
        except DgsdpError as e:
            raise gr.Error(str(e)) from None
        if not genres:
            return gr.update(choices=[], value=None), f"Loaded {checkpoint} (a model without style conditioning)."
        value = genre if genre in genres else genres[0]
        return gr.update(choices=genres, value=value), f"Loaded {checkpoint}."

    def on_timeline(self, rows: Any, song: str | None, request: gr.Request | None = None) -> tuple[str, str]:
        """The schedule string of the timeline rows and a bar drawing the spans along the song (another login's
        song is not read: the bar is drawn without the song's length)."""
        try:
            text = schedule_text(rows)
        except DgsdpError as e:
            return f"error: {e}", ""
        if not text:
            return "(no schedule: the style above is used for the whole song)", ""
        seconds = None
        if song and self.access.may_use(self.login(request), song):
            with contextlib.suppress(Exception):  # an unreadable song is reported when generating
                info = sf.info(song)
                seconds = info.frames / info.samplerate
        return text, timeline_html(parse_schedule(text), seconds)

    def run(
        self,
        request: eng.DanceRequest,
        progress: gr.Progress,
        login: str | None = None,
    ) -> tuple[str, list[str], dict, str]:
        """Run one request into a fresh folder of the login's; return the viewer value, files, session state and a
        status line."""
        limit = self.config.request_timeout_s
        folder = self.request_folder(login)
        try:
            with time_limit(limit, f"the request was stopped at the studio's time limit of {limit:g} s per "
                            "request (--request-timeout); try a shorter song, fewer steps or no video"):  # fmt: skip
                song = folder / f"{_safe_name(request.song.stem)}{request.song.suffix.lower()}"
                shutil.copyfile(request.song, song)
                request.song = song
                progress(0.02, desc="reading the song")
                seconds = self.engine.song_seconds(song)
                progress(0.05, desc="loading the model")
                self.engine.generator(request.checkpoint)
                started = time.perf_counter()
                dance = self.engine.run(request, folder / song.stem, progress=True)
                elapsed = time.perf_counter() - started
            progress(0.98, desc="preparing the viewer")
            # writing it marks the run finished
            joints_path = write_joints_json(folder / "viewer.json", dance.joints, dance.fps, skeleton=dance.skeleton)
        except Exception:
            shutil.rmtree(folder, ignore_errors=True)  # nothing half-written stays behind
            raise
        self.prune()
        npy = next(f for f in dance.files if f.suffix == ".npy")
        label = f"{song.stem}  |  {dance.style}" if dance.style else song.stem
        value = viewer_value(_file_url(joints_path), _file_url(song), len(dance.joints), dance.fps, label)
        state = {"motion": str(npy), "song": str(song), "fps": dance.fps, "checkpoint": request.checkpoint}
        shown = folder.relative_to(self.work_dir.parent)  # e.g. studio/runs/<time>-<id>, runs/<login folder>/...
        status = f"{len(dance.joints)} frames ({seconds:.1f} s) generated in {elapsed:.1f} s; files in {shown}"
        if dance.notes:  # half or double time, beat sync's choice
            status += "; " + "; ".join(dance.notes)
        return value, [str(f) for f in dance.files], state, status

    def on_generate(
        self, song, checkpoint, genre, free_text, rows, music_w, style_w, sampler, steps, seed, video, cleanup=True,
        progress=gr.Progress(track_tqdm=True), request: gr.Request | None = None,
    ):  # fmt: skip
        try:
            login = self.login(request)
            dance = eng.DanceRequest(
                checkpoint=self.checkpoint_path(checkpoint), song=self.check_song(song, login),
                style=style_text(genre, free_text, rows), **sampling_values(music_w, style_w, sampler, steps, seed),
                video=bool(video), cleanup=bool(cleanup),
            )  # fmt: skip
            return self.run(dance, progress, login)
        except DgsdpError as e:
            raise gr.Error(str(e)) from None

    def on_edit(
        self, current, song, checkpoint, genre, free_text, rows, music_w, style_w, sampler, steps, seed, video,
        edit_label, keyframe_text, seed_seconds, range_start, range_end, cleanup=True,
        progress=gr.Progress(track_tqdm=True), request: gr.Request | None = None,
    ):  # fmt: skip
        try:
            login = self.login(request)
            if not current or not self.access.may_use(login, current["motion"]):  # a dance of this login's only
                raise ConfigError("generate a dance first; edits change the current dance")
            kind = EDIT_LABELS.get(edit_label, edit_label)
            if not Path(current["motion"]).is_file():
                raise ConfigError("the current dance's files were removed from the server; generate a new dance")
            motion = np.load(current["motion"], allow_pickle=False)
            edit = eng.Edit(
                kind=kind, motion=motion, keyframe_seconds=eng.parse_seconds(keyframe_text),
                seed_seconds=finite(seed_seconds or 0, "Continue: seconds kept from the end"),
                start_seconds=finite(range_start or 0, "Range start"), end_seconds=finite(range_end or 0, "Range end"),
            )  # fmt: skip
            # Edits keep the current dance's song; continuing dances on to the song in the upload box.
            target_song = self.check_song(song, login) if kind == "continue" else Path(current["song"])
            dance = eng.DanceRequest(
                checkpoint=self.checkpoint_path(checkpoint), song=target_song, style=style_text(genre, free_text, rows),
                **sampling_values(music_w, style_w, sampler, steps, seed), video=bool(video), edit=edit,
                cleanup=bool(cleanup),
            )  # fmt: skip
            return self.run(dance, progress, login)
        except DgsdpError as e:
            raise gr.Error(str(e)) from None


def sampling_values(music_w: Any, style_w: Any, sampler: Any, steps: Any, seed: Any) -> dict[str, Any]:
    """The sampling fields of a request, checked to be finite numbers (one message naming the field)."""
    return {
        "music_weight": finite(music_w, "Music guidance"), "style_weight": finite(style_w, "Style guidance"),
        "sampler": str(sampler), "steps": finite(steps, "Steps", integer=True), "seed": finite(seed, "Seed", integer=True),
    }  # fmt: skip


def _entries(folder: Path) -> list[Path]:
    """The entries of a folder ([] when it is missing or not a folder)."""
    with contextlib.suppress(OSError):
        return list(folder.iterdir())
    return []


def _by_age(paths: list[Path]) -> list[Path]:
    """``paths`` newest first (by modification time; paths removed meanwhile are dropped)."""
    entries = []
    for path in paths:
        with contextlib.suppress(OSError):  # removed meanwhile
            entries.append((path.stat().st_mtime, path))
    return [path for _, path in sorted(entries, key=lambda e: e[0], reverse=True)]


def _newest_first(folder: Path) -> list[Path]:
    """The entries of a folder, newest first."""
    return _by_age(_entries(folder))


def _age_s(path: Path) -> float:
    try:
        return time.time() - path.stat().st_mtime
    except OSError:
        return 0.0


def _file_url(path: Path) -> str:
    return f"/gradio_api/file={path}"


def build_app(config: StudioConfig, engine: eng.Engine | None = None) -> tuple[gr.Blocks, Studio]:
    """The studio's Gradio Blocks (not launched) and its handlers."""
    studio = Studio(config, engine)
    studio.prune()
    # Dances and example songs are served from where they are written, not copied into Gradio's upload folder:
    # each file has one place, whose folder says whose it is, and the upload folder holds uploads only.
    gr.set_static_paths([studio.work_dir / "runs", studio.work_dir / "examples"])
    checkpoints = studio.checkpoints()
    genres = list(AISTPP_GENRES.names)
    with gr.Blocks(title="dgsdp studio", analytics_enabled=False) as demo:
        gr.Markdown(
            "## dgsdp studio\nA song and a style in, a dance out: watch it with the music, edit it, download it."
        )
        current = gr.State(None)
        with gr.Row():
            with gr.Column(scale=2, min_width=320):
                song = gr.File(label="Song (wav, mp3, ogg, flac)", file_types=list(AUDIO_TYPES), type="filepath",
                               elem_id="song")  # fmt: skip
                example = gr.Dropdown(genres, value=None, label="...or an example song (synthetic, 10 s)",
                                      elem_id="example")  # fmt: skip
                typed = ", or type the path of a .ckpt" if config.allow_checkpoint_paths else ""
                checkpoint = gr.Dropdown(  # a custom value reaches Studio.checkpoint_path, which says what to do
                    checkpoints, value=checkpoints[0] if checkpoints else None, allow_custom_value=True,
                    label=f"Model (runs under the outputs folder{typed})", elem_id="checkpoint",
                )  # fmt: skip
                model_status = gr.Markdown("", elem_id="model-status")
                with gr.Row():
                    genre = gr.Dropdown(genres, value=genres[0], label="Genre", elem_id="genre")
                    free_text = gr.Textbox(label="...or describe the style", placeholder="sharp, powerful krump",
                                           max_length=MAX_STYLE_CHARS, elem_id="style-text")  # fmt: skip
                with gr.Accordion("Style timeline (a style per span of the song)", open=False):
                    rows = gr.Dataframe(
                        headers=SCHEDULE_HEADERS, datatype=["number", "str", "str"], column_count=3,
                        row_count=1, interactive=True, label="Spans (seconds)", elem_id="timeline",
                    )  # fmt: skip
                    schedule_preview = gr.Textbox(label="Schedule", interactive=False, elem_id="schedule")
                    timeline_bar = gr.HTML("", elem_id="timeline-bar")
                with gr.Accordion("Sampling", open=False):
                    music_w = gr.Slider(0, 5, value=GuidanceSettings.music, step=0.1, label="Music guidance")
                    style_w = gr.Slider(
                        0, 5, value=1.0, step=0.1, label="Style guidance (models trained with style dropout)"
                    )
                    sampler = gr.Radio(list(METHODS), value=SamplingSettings.method, label="Sampler")
                    steps = gr.Slider(1, 1000, value=config.default_steps, step=1, label="Steps",
                                      elem_id="steps")  # fmt: skip
                    seed = gr.Number(value=0, label="Seed")  # whole numbers: checked by the handler
                    video = gr.Checkbox(value=True, label="Render an mp4 video")
                    cleanup = gr.Checkbox(
                        value=True, label="Finish the dance (on the beat, feet on the floor)", elem_id="cleanup"
                    )
                generate = gr.Button("Generate", variant="primary", elem_id="generate")
            with gr.Column(scale=3, min_width=420):
                viewer = gr.HTML(
                    "", html_template=HTML_TEMPLATE, css_template=CSS_TEMPLATE, js_on_load=JS_ON_LOAD,
                    elem_id="viewer",
                )  # fmt: skip
                status = gr.Markdown("", elem_id="status")
                with gr.Accordion("Edit the current dance", open=False):
                    edit_kind = gr.Radio(list(EDIT_LABELS), value=next(iter(EDIT_LABELS)), label="Edit",
                                         elem_id="edit-kind")  # fmt: skip
                    with gr.Row():
                        keyframes = gr.Textbox(label="Keyframes (seconds)", placeholder="1.5, 4, 8")
                        seed_seconds = gr.Number(value=1.0, label="Continue: seconds kept from the end")
                    with gr.Row():
                        range_start = gr.Number(value=2.0, label="Range start (s)", elem_id="range-start")
                        range_end = gr.Number(value=4.0, label="Range end (s)", elem_id="range-end")
                    apply_edit = gr.Button("Apply edit", elem_id="apply-edit")
                kinds = "AIST++ pkl, BVH, GLB, mp4, npy" if eng.glb_available() else "AIST++ pkl, BVH, mp4, npy"
                downloads = gr.File(label=f"Downloads: {kinds}", file_count="multiple",
                                    interactive=False, elem_id="downloads")  # fmt: skip

        settings = [checkpoint, genre, free_text, rows, music_w, style_w, sampler, steps, seed, video]
        outputs = [viewer, downloads, current, status]
        example.change(studio.on_example, [example], [song])
        rows.change(studio.on_timeline, [rows, song], [schedule_preview, timeline_bar])
        song.change(studio.on_timeline, [rows, song], [schedule_preview, timeline_bar])
        checkpoint.change(studio.on_checkpoint, [checkpoint, genre], [genre, model_status],
                          concurrency_id="model", concurrency_limit=1)  # fmt: skip
        demo.load(studio.on_checkpoint, [checkpoint, genre], [genre, model_status], concurrency_id="model")
        generate.click(
            studio.on_generate, [song, *settings, cleanup], outputs, concurrency_id="model", concurrency_limit=1
        )
        apply_edit.click(
            studio.on_edit,
            [current, song, *settings, edit_kind, keyframes, seed_seconds, range_start, range_end, cleanup],
            outputs,
            concurrency_id="model",
            concurrency_limit=1,
        )
    demo.queue(max_size=config.queue_size, default_concurrency_limit=1)
    return demo, studio


def theme() -> gr.themes.Base:
    """Gradio's default look with system fonts (the default theme loads web fonts from the internet)."""
    return gr.themes.Default(
        font=["ui-sans-serif", "system-ui", "sans-serif"], font_mono=["ui-monospace", "Consolas", "monospace"]
    )


def launch_kwargs(config: StudioConfig, studio: Studio) -> dict[str, Any]:
    """``demo.launch`` arguments: the address, the files it may serve, the upload limit, the logins (and with them,
    the check that serves each login only its own files)."""
    from starlette.middleware import Middleware

    return {
        "auth": list(config.auth) or None,
        "app_kwargs": {"middleware": [Middleware(LoginFiles, access=studio.access)]} if config.auth else None,
        "auth_message": "Log in to the dgsdp studio." if config.auth else None,
        "server_name": config.host,
        "server_port": config.port,
        "allowed_paths": [str(studio.work_dir)],
        "max_file_size": f"{config.max_upload_mb:g}mb",
        "theme": theme(),
        "ssr_mode": False,
        "show_error": True,
        "share": False,
        "inbrowser": False,
        "footer_links": [],
    }


def parse_args(argv: list[str] | None = None) -> StudioConfig:
    defaults = StudioConfig()
    p = argparse.ArgumentParser(prog="dgsdp-studio", description="The dgsdp dance studio: a local web page.")
    p.add_argument("--checkpoint", default=None, help="a trained model's .ckpt (default: the newest run's last.ckpt)")
    p.add_argument("--host", default=defaults.host, help="address to serve on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=defaults.port, help="port (default 7860)")
    p.add_argument("--outputs", default=defaults.outputs, help="folder searched for runs (*/checkpoints/last.ckpt)")
    p.add_argument("--work-dir", default=defaults.work_dir, help="where generated dances are written")
    p.add_argument("--max-upload-mb", type=float, default=defaults.max_upload_mb, help="largest song upload (MB)")
    p.add_argument("--max-seconds", type=float, default=defaults.max_song_seconds, help="longest song (seconds)")
    p.add_argument("--device", default=defaults.device, help="auto, cpu or cuda")
    p.add_argument("--queue-size", type=int, default=defaults.queue_size, help="requests that may wait in the queue")
    p.add_argument("--steps", type=int, default=defaults.default_steps, help="default number of sampling steps")
    shared = p.add_argument_group("sharing the studio (docs/studio.md)")
    shared.add_argument("--auth", action="append", default=[], metavar="USER:PASSWORD",
                        help="require this login (repeat for more users); recommended with --host beyond 127.0.0.1")  # fmt: skip
    shared.add_argument("--auth-file", metavar="FILE",
                        help="require one of the logins in FILE (a USER:PASSWORD per line; # starts a comment)")  # fmt: skip
    shared.add_argument("--allow-checkpoint-paths", action="store_true",
                        help="let users type the path of any .ckpt on this machine into the Model box "
                        "(default: only the listed runs)")  # fmt: skip
    shared.add_argument("--request-timeout", type=float, default=defaults.request_timeout_s, metavar="SECONDS",
                        help=f"stop a request after this long so the queue moves on (default {defaults.request_timeout_s:g})")  # fmt: skip
    shared.add_argument("--keep-runs", type=int, default=defaults.keep_runs, metavar="N",
                        help=f"keep the newest N generated dances (run folders) and song uploads, remove older ones "
                        f"(default {defaults.keep_runs}; 0 keeps everything)")  # fmt: skip
    limits = p.add_argument_group("finishing limits (generate.py's finishing keys; docs/floor.md, docs/beatsync.md)")
    f = defaults.finishing
    for key, metavar, what in (
        ("max_turn_rate", "RAD_S", "fastest turn of the body's facing"),
        ("max_tilt_rate", "RAD_S", "fastest tilt of the body's up axis"),
        ("max_air_seconds", "S", "longest jump without foot contact"),
    ):
        default = getattr(f, key)
        limits.add_argument(
            "--" + key.replace("_", "-"),
            type=_limit,
            default=default,
            metavar=f"{metavar}|none",
            help=f"{what} (default {'none' if default is None else f'{default:g}'}; none: no limit)",
        )
    limits.add_argument(
        "--beat-sync-reach",
        type=float,
        default=f.beat_sync_reach,
        metavar="BEATS",
        help=f"how far a pause may move onto a beat (default {f.beat_sync_reach:g}, at most 0.5)",
    )
    a = p.parse_args(argv)
    try:
        finishing = Finishing(a.max_turn_rate, a.max_tilt_rate, a.max_air_seconds, a.beat_sync_reach)
        logins = [parse_login(text, "--auth") for text in a.auth] + (read_logins(a.auth_file) if a.auth_file else [])
    except ConfigError as e:
        p.error(str(e))
    if not (a.request_timeout > 0 and math.isfinite(a.request_timeout)):
        p.error(f"--request-timeout must be a positive number of seconds, got {a.request_timeout:g}")
    if a.keep_runs < 0:
        p.error(f"--keep-runs must be 0 (keep everything) or more, got {a.keep_runs}")
    return StudioConfig(
        checkpoint=a.checkpoint, host=a.host, port=a.port, outputs=a.outputs, work_dir=a.work_dir,
        max_upload_mb=a.max_upload_mb, max_song_seconds=a.max_seconds, device=a.device, queue_size=a.queue_size,
        default_steps=a.steps, finishing=finishing, allow_checkpoint_paths=a.allow_checkpoint_paths,
        request_timeout_s=a.request_timeout, keep_runs=a.keep_runs, auth=logins,
    )  # fmt: skip


def parse_login(text: str, where: str) -> tuple[str, str]:
    """``user:password`` as a (user, password) pair; ConfigError saying where the bad login came from."""
    user, sep, password = text.strip().partition(":")
    if not sep or not user or not password:
        raise ConfigError(f"{where}: a login is USER:PASSWORD with neither part empty")
    return user, password


def read_logins(path: str) -> list[tuple[str, str]]:
    """The logins of an ``--auth-file`` (``user:password`` per line; blank lines and # comments skipped)."""
    try:
        lines = Path(path).expanduser().read_text().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"--auth-file {path}: cannot read it ({e})") from None
    logins = [
        parse_login(line, f"--auth-file {path}, line {i}")
        for i, line in enumerate(lines, 1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not logins:
        raise ConfigError(f"--auth-file {path} has no login; write one USER:PASSWORD per line")
    return logins


def is_loopback(host: str) -> bool:
    """Whether serving on ``host`` reaches this machine only."""
    return host in LOOPBACK_HOSTS or host.startswith("127.")


def sharing_warning(config: StudioConfig) -> str | None:
    """The warning printed when the studio is served beyond this machine (None on a loopback address)."""
    if is_loopback(config.host):
        return None
    text = f"warning: --host {config.host} serves the studio to the network: everyone who can reach port {config.port}"
    if not config.auth:
        text += " can use it, with no login. Add --auth USER:PASSWORD or --auth-file FILE (docs/studio.md)."
    else:
        text += f" gets a login page ({len(config.auth)} login(s) set). The connection is not encrypted (http)."
    if config.allow_checkpoint_paths:
        text += " With --allow-checkpoint-paths, users can open any .ckpt on this machine."
    return text


def _limit(text: str) -> float | None:
    """A limit on the command line: a number, or none (no limit)."""
    return None if text.strip().lower() in ("none", "null", "off") else float(text)


def main(argv: list[str] | None = None) -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    config = parse_args(argv)
    if config.checkpoint and not Path(config.checkpoint).expanduser().is_file():
        raise SystemExit(f"error: checkpoint {config.checkpoint} does not exist; check the path")
    warning = sharing_warning(config)
    if warning:
        print(warning, file=sys.stderr, flush=True)
    # Uploads go into the work folder, where --keep-runs prunes them (not the machine-wide temp folder).
    os.environ["GRADIO_TEMP_DIR"] = str(Path(config.work_dir).expanduser().resolve() / "uploads")
    demo, studio = build_app(config)
    print(f"dgsdp studio: open http://{config.host}:{config.port} in a browser (Ctrl+C stops it)", flush=True)
    demo.launch(**launch_kwargs(config, studio))
