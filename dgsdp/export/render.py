"""Stick-figure videos of a dance, with the music: mp4 through ffmpeg, or a silent GIF when ffmpeg is missing.

The view is an orthographic camera (``Camera``) that follows the dancer: each frame's camera looks at the root's
horizontal position smoothed over time (a zero-lag Gaussian of ``FOLLOW_SMOOTH_SECONDS``), at one height and one
zoom for the whole video, chosen so that every joint of every frame stays in view (``follow_cameras``). Pass a
``Camera`` (for example from ``fit_camera``) for a fixed view instead. The floor grid is drawn at the true floor,
``floor_z`` (the run's floor height, :mod:`dgsdp.motion.floor`; 0 for the synthetic data), not at the lowest joint,
so jumps leave the floor and joints below it show. Joints are z-up metres (FK output) of the motion's skeleton
(:class:`~dgsdp.motion.Skeleton`, default SMPL-24), whose parents give the bones.
Bones are coloured by side: left blue, right red, centre grey, and drawn far to near. A title is wrapped onto
lines, and shrunk if needed, so that it fits the image width.

Video and audio: the video has exactly one frame per motion frame. The song is decoded with the project's audio
loader, cut to the motion's duration (N / fps seconds) and muxed as AAC; both streams start at time 0, so frame i
is shown while the music at i / fps seconds plays. A song shorter than the motion ends before the video does.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf
import torch
from PIL import Image, ImageDraw, ImageFont

from dgsdp.audio.io import load_audio
from dgsdp.errors import ConfigError, DataError, DgsdpError
from dgsdp.motion import SMPL24, Skeleton
from dgsdp.utils.deadline import check_time, seconds_left
from dgsdp.utils.io import atomic_path, owner_gone, temp_tag

BACKGROUND = (255, 255, 255)
FLOOR_COLOUR = (200, 200, 200)
LEFT_COLOUR = (40, 90, 200)
RIGHT_COLOUR = (210, 50, 50)
CENTRE_COLOUR = (70, 70, 70)
TEXT_COLOUR = (0, 0, 0)
HEAD_RADIUS_M = 0.09
GRID_STEP_M = 0.5
AUDIO_BITRATE = "192k"
FOLLOW_SMOOTH_SECONDS = 0.5
TITLE_MAX_LINES = 3
MIN_TITLE_PX = 8


@functools.lru_cache(maxsize=8)
def _font(size_px: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size=size_px)


def _side_colour(name: str) -> tuple[int, int, int]:
    if name.startswith("left"):
        return LEFT_COLOUR
    if name.startswith("right"):
        return RIGHT_COLOUR
    return CENTRE_COLOUR


@dataclass(frozen=True)
class Camera:
    """Orthographic camera looking at ``target`` (z-up metres); ``extent_m`` metres span the shorter image side.

    Azimuth 0 and elevation 0 look along +y (from in front of a body facing -y, SMPL's rest facing in our z-up
    world): screen right is +x, screen up is +z. A positive azimuth turns the camera counter-clockwise about z
    (seen from above); a positive elevation raises it, looking down.
    """

    target: tuple[float, float, float]
    extent_m: float
    azimuth_deg: float = 20.0
    elevation_deg: float = 15.0
    floor_z: float = 0.0  # height of the floor grid (metres); the dataset's floor is z = 0

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit vectors (right, up, towards the camera), each (3,)."""
        az, el = math.radians(self.azimuth_deg), math.radians(self.elevation_deg)
        right = np.array([math.cos(az), math.sin(az), 0.0])
        towards = np.array([math.cos(el) * math.sin(az), -math.cos(el) * math.cos(az), math.sin(el)])
        up = np.cross(towards, right)
        return right, up, towards

    def project(self, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """(..., 3) z-up metres -> (..., 2) pixel coordinates (x right, y down) in an image of ``size`` (W, H)."""
        width, height = size
        right, up, _ = self.axes()
        rel = np.asarray(points, dtype=np.float64) - np.asarray(self.target, dtype=np.float64)
        scale = min(width, height) / self.extent_m
        return np.stack((width / 2 + scale * rel @ right, height / 2 - scale * rel @ up), axis=-1)

    def pixels_per_metre(self, size: tuple[int, int]) -> float:
        return min(size) / self.extent_m


def fit_camera(
    joints: torch.Tensor | np.ndarray,
    azimuth_deg: float = 20.0,
    elevation_deg: float = 15.0,
    margin: float = 0.15,
    floor_z: float = 0.0,
) -> Camera:
    """A fixed camera that keeps every joint of every frame in view. joints: (T, J, 3) or (J, 3), z-up metres.

    ``margin`` is the fraction of the view left free around the figure; the floor grid is drawn at ``floor_z``.
    """
    pts = _as_joints(joints).reshape(-1, 3)
    probe = Camera((0.0, 0.0, 0.0), 1.0, azimuth_deg, elevation_deg)
    right, up, _ = probe.axes()
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    along_right, along_up = pts @ right, pts @ up
    centre_right = (along_right.min() + along_right.max()) / 2
    centre_up = (along_up.min() + along_up.max()) / 2
    # The point of the box's vertical centre line that projects to the centre of the on-screen box.
    middle = (lo + hi) / 2
    target = middle + right * (centre_right - middle @ right) + up * (centre_up - middle @ up)
    span = max(np.ptp(along_right), np.ptp(along_up), 1.0) + 2 * HEAD_RADIUS_M
    extent = span / max(1.0 - 2 * margin, 0.1)
    return Camera(tuple(float(v) for v in target), float(extent), azimuth_deg, elevation_deg, float(floor_z))


def follow_cameras(
    joints: torch.Tensor | np.ndarray,
    fps: float = 30,
    azimuth_deg: float = 20.0,
    elevation_deg: float = 15.0,
    margin: float = 0.15,
    smooth_seconds: float = FOLLOW_SMOOTH_SECONDS,
    floor_z: float = 0.0,
) -> list[Camera]:
    """One camera per frame following the dancer. joints: (T, J, 3) z-up metres; the root is joint 0.

    The target's x and y are the root's, smoothed by a Gaussian of ``smooth_seconds`` (standard deviation; no lag,
    as the filter is centred); its height and the zoom are the same for all frames, chosen so that every joint of
    every frame, and the floor point below the target, are in view with ``margin`` of the view free around them.
    """
    from scipy.ndimage import gaussian_filter1d

    motion = _as_joints(joints)
    if motion.ndim != 3:
        raise DataError(f"follow_cameras needs a motion (T, J, 3), got shape {motion.shape}")
    if not fps > 0 or not smooth_seconds >= 0:
        raise ConfigError(f"fps must be positive and smooth_seconds non-negative, got {fps} and {smooth_seconds}")
    root_xy = motion[:, 0, :2]
    sigma = smooth_seconds * fps
    centre_xy = gaussian_filter1d(root_xy, sigma, axis=0, mode="nearest") if sigma > 0 else root_xy
    probe = Camera((0.0, 0.0, 0.0), 1.0, azimuth_deg, elevation_deg)
    right, up, _ = probe.axes()
    floor = np.concatenate((centre_xy, np.full((len(motion), 1), floor_z)), axis=-1)[:, None]  # under the target
    rel = np.concatenate((motion, floor), axis=1)  # joints and the floor below them stay in view
    rel[..., :2] -= centre_xy[:, None, :]  # relative to a target at height 0
    along_right, along_up = rel @ right, rel @ up
    # Raising the target by h moves every point down the screen by h * up_z: centre the on-screen height range.
    middle_up = (along_up.min() + along_up.max()) / 2
    target_z = middle_up / up[2] if up[2] > 1e-6 else float(motion[..., 2].mean())
    half_width = np.abs(along_right).max()
    span = max(2 * half_width, np.ptp(along_up), 1.0) + 2 * HEAD_RADIUS_M
    extent = float(span / max(1.0 - 2 * margin, 0.1))
    return [
        Camera((float(x), float(y), float(target_z)), extent, azimuth_deg, elevation_deg, float(floor_z))
        for x, y in centre_xy
    ]


def _as_joints(joints: torch.Tensor | np.ndarray, skeleton: Skeleton | None = None) -> np.ndarray:
    """Joints (T, J, 3) or (J, 3) as float64, J the skeleton's number of joints (any without a skeleton)."""
    arr = joints.detach().cpu().numpy() if torch.is_tensor(joints) else np.asarray(joints)
    arr = arr.astype(np.float64)
    n = "J" if skeleton is None else skeleton.num_joints
    wrong_count = skeleton is not None and arr.shape[-2:-1] != (skeleton.num_joints,)
    if arr.ndim not in (2, 3) or arr.size == 0 or arr.shape[-1] != 3 or wrong_count:
        raise DataError(f"joints must be (T, {n}, 3) or ({n}, 3) z-up metres, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise DataError("joints have NaN or infinite values; check the generated motion")
    return arr


def _check_size(size: Sequence[int]) -> tuple[int, int]:
    if len(size) != 2 or min(int(size[0]), int(size[1])) < 16:
        raise ConfigError(f"render size must be (width, height) of at least 16 pixels each, got {size}")
    return int(size[0]), int(size[1])


def _draw_floor(draw: ImageDraw.ImageDraw, camera: Camera, size: tuple[int, int], width_px: int) -> None:
    half = camera.extent_m
    cx, cy = camera.target[0], camera.target[1]
    start_x = math.floor((cx - half) / GRID_STEP_M) * GRID_STEP_M
    start_y = math.floor((cy - half) / GRID_STEP_M) * GRID_STEP_M
    n = int(math.ceil(2 * half / GRID_STEP_M)) + 1
    z = camera.floor_z
    for i in range(n + 1):
        gx, gy = start_x + i * GRID_STEP_M, start_y + i * GRID_STEP_M
        end_x = start_x + n * GRID_STEP_M
        end_y = start_y + n * GRID_STEP_M
        for seg in (((gx, start_y, z), (gx, end_y, z)), ((start_x, gy, z), (end_x, gy, z))):
            (x0, y0), (x1, y1) = camera.project(np.array(seg), size)
            draw.line([(x0, y0), (x1, y1)], fill=FLOOR_COLOUR, width=width_px)


def render_frame(
    joints_t: torch.Tensor | np.ndarray,
    camera: Camera | None = None,
    size: tuple[int, int] = (480, 480),
    title: str | None = None,
    skeleton: Skeleton = SMPL24,
) -> np.ndarray:
    """Draw one pose (J, 3) of ``skeleton``, z-up metres, as a stick figure. Returns an (H, W, 3) uint8 RGB image.

    ``camera`` defaults to one fitted to this pose alone; pass one fitted to the whole motion (``fit_camera``)
    to keep the view fixed over a video.
    """
    size = _check_size(size)
    return _draw_frame(joints_t, camera, size, _title_layout(title, size), skeleton)


TitleLayout = tuple[list[str], ImageFont.FreeTypeFont | ImageFont.ImageFont]


def _line_px(size: tuple[int, int]) -> int:
    return max(1, round(min(size) / 120))


def _title_layout(title: str | None, size: tuple[int, int]) -> TitleLayout | None:
    """The title's lines and font in an image of ``size`` (fitted once per video: fitting costs more than a frame)."""
    if not title:
        return None
    return fit_title(title, size[0] - 8 * _line_px(size), max(10, min(size) // 24))


def _draw_frame(
    joints_t: torch.Tensor | np.ndarray,
    camera: Camera | None,
    size: tuple[int, int],
    title: TitleLayout | None,
    skeleton: Skeleton,
) -> np.ndarray:
    pose = _as_joints(joints_t, skeleton)
    if pose.ndim != 2:
        raise DataError(f"render_frame draws one pose ({skeleton.num_joints}, 3), got shape {pose.shape}")
    camera = camera or fit_camera(pose)
    image = Image.new("RGB", size, BACKGROUND)
    draw = ImageDraw.Draw(image)
    line_px = _line_px(size)
    _draw_floor(draw, camera, size, max(1, line_px // 2))

    px = camera.project(pose, size)
    _, _, towards = camera.axes()
    nearness = pose @ towards
    parents, names = skeleton.parents, skeleton.joint_names
    bones = list(range(1, skeleton.num_joints))
    bones.sort(key=lambda j: nearness[j] + nearness[parents[j]])  # far to near
    for j in bones:
        p = parents[j]
        draw.line([tuple(px[p]), tuple(px[j])], fill=_side_colour(names[j]), width=line_px)
    r = max(3.0, 1.2 * line_px)
    for j in range(skeleton.num_joints):
        x, y = px[j]
        draw.ellipse([x - r, y - r, x + r, y + r], fill=_side_colour(names[j]))
    if "head" in names:
        head_r = HEAD_RADIUS_M * camera.pixels_per_metre(size)
        hx, hy = px[names.index("head")]
        draw.ellipse([hx - head_r, hy - head_r, hx + head_r, hy + head_r], outline=CENTRE_COLOUR, width=line_px)
    if title is not None:
        lines, font = title
        y = line_px * 3
        for line in lines:
            draw.text((line_px * 4, y), line, fill=TEXT_COLOUR, font=font)
            y += _line_height(font)
    return np.asarray(image, dtype=np.uint8)


def _line_height(font: ImageFont.FreeTypeFont | ImageFont.ImageFont) -> int:
    box = font.getbbox("Ag")
    return int(math.ceil((box[3] - box[1]) * 1.25))


def _wrap(
    words: list[str], font: ImageFont.FreeTypeFont | ImageFont.ImageFont, width_px: int, max_lines: int
) -> list[str]:
    """Words onto lines of at most ``width_px`` (a word wider than that gets a line of its own); stops after
    ``max_lines + 1`` lines, which is enough to know the text does not fit (a long text costs no more)."""
    lines: list[str] = []
    for word in words:
        if lines and font.getlength(f"{lines[-1]} {word}") <= width_px:
            lines[-1] = f"{lines[-1]} {word}"
        elif len(lines) > max_lines:
            break
        else:
            lines.append(word)
    return lines


def _cut(line: str, font: ImageFont.FreeTypeFont | ImageFont.ImageFont, width_px: int) -> str:
    """The longest start of ``line`` that fits ``width_px`` with "..." after it (a binary search on its length)."""
    low, high = 0, len(line)  # line[:low] + "..." fits (or low is 0); line[:high + 1] + "..." does not
    while low < high:
        mid = (low + high + 1) // 2
        if font.getlength(line[:mid] + "...") <= width_px:
            low = mid
        else:
            high = mid - 1
    return line[:low] + "..."


def fit_title(title: str, width_px: int, size_px: int) -> TitleLayout:
    """Lines and font for ``title`` within ``width_px``: wrapped at spaces onto at most ``TITLE_MAX_LINES`` lines,
    the font shrunk from ``size_px`` down to ``MIN_TITLE_PX`` until every line fits. A title that does not fit
    even then is cut, and the cut marked with "..."."""
    # A glyph is at least a pixel wide: past these many characters (or a word's width_px) nothing more can show.
    title = title[: (TITLE_MAX_LINES + 1) * max(width_px, 1)]
    words = [word[: max(width_px, 1) + 1] for word in title.split()] or [title]
    for px in range(size_px, MIN_TITLE_PX - 1, -1):
        font = _font(px)
        lines = _wrap(words, font, width_px, TITLE_MAX_LINES)
        if len(lines) <= TITLE_MAX_LINES and all(font.getlength(line) <= width_px for line in lines):
            return lines, font
    font = _font(MIN_TITLE_PX)
    lines = _wrap(words, font, width_px, TITLE_MAX_LINES)
    cut_after = len(lines) > TITLE_MAX_LINES
    fitted = []
    for i, line in enumerate(lines[:TITLE_MAX_LINES]):
        if font.getlength(line) > width_px or (cut_after and i == TITLE_MAX_LINES - 1):
            line = _cut(line, font, width_px)
        fitted.append(line)
    return fitted, font


def ffmpeg_available() -> bool:
    """Whether an ``ffmpeg`` executable is on PATH."""
    return shutil.which("ffmpeg") is not None


def _frames(
    joints: np.ndarray, cameras: Sequence[Camera], size: tuple[int, int], title: str | None, skeleton: Skeleton
) -> Iterator[np.ndarray]:
    layout = _title_layout(title, size)
    for pose, camera in zip(joints, cameras, strict=True):
        check_time()  # a request's time limit (dgsdp.utils.deadline), when one is set
        yield _draw_frame(pose, camera, size, layout, skeleton)


def _write_gif(tmp: Path, frames: Iterator[np.ndarray], fps: float) -> None:
    """Silent GIF. Delays are stored in hundredths of a second (30 FPS plays at about 33 FPS); identical
    consecutive frames are merged into one longer frame. Frames are kept in memory as 1 byte per pixel."""
    images = (Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE, colors=64) for f in frames)
    first = next(images)
    first.save(tmp, format="GIF", save_all=True, append_images=images, duration=1000.0 / fps, loop=0)


FFMPEG_STALL_SECONDS = 120.0
"""Default of ``DGSDP_FFMPEG_TIMEOUT``: ffmpeg is killed when it accepts no frame for this long, or takes this long plus the song's duration to finish
after the last frame (a pathological input once made the AAC encode hang for 20 minutes)."""
RENDER_TEMP_PREFIX = "dgsdp-render-"


def ffmpeg_timeout_seconds() -> float:
    """``DGSDP_FFMPEG_TIMEOUT`` (seconds), else :data:`FFMPEG_STALL_SECONDS`."""
    raw = os.environ.get("DGSDP_FFMPEG_TIMEOUT")
    try:
        value = float(raw) if raw else FFMPEG_STALL_SECONDS
    except ValueError:
        raise ConfigError(f"DGSDP_FFMPEG_TIMEOUT must be a number of seconds, got {raw!r}") from None
    if not value > 0:
        raise ConfigError(f"DGSDP_FFMPEG_TIMEOUT must be positive, got {raw!r}")
    return value


class _Watchdog:
    """Kills a process (and its process group) when ``deadline`` passes; push the deadline to keep it alive."""

    def __init__(self, proc: subprocess.Popen, stall_seconds: float) -> None:
        self.proc = proc
        self.deadline = time.monotonic() + stall_seconds
        self.fired = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.2):
            if time.monotonic() > self.deadline and self.proc.poll() is None:
                self.fired = True
                _kill(self.proc)
                return

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def _kill(proc: subprocess.Popen) -> None:
    with contextlib.suppress(OSError):
        if os.name == "posix":
            os.killpg(proc.pid, signal.SIGKILL)
        else:
            proc.kill()


def _remove_stale_render_dirs() -> None:
    """Remove render folders of killed processes of this machine from the temp folder."""
    for folder in Path(tempfile.gettempdir()).glob(f"{RENDER_TEMP_PREFIX}*"):
        match = re.match(rf"{RENDER_TEMP_PREFIX}(?P<tag>.+-\d+)-", folder.name)
        if match and folder.is_dir() and owner_gone(match["tag"], folder):
            shutil.rmtree(folder, ignore_errors=True)


def _write_mp4(
    tmp: Path,
    frames: Iterator[np.ndarray],
    n_frames: int,
    fps: float,
    size: tuple[int, int],
    audio_path: Path | None,
) -> None:
    stall_seconds = ffmpeg_timeout_seconds()
    _remove_stale_render_dirs()
    with tempfile.TemporaryDirectory(prefix=f"{RENDER_TEMP_PREFIX}{temp_tag()}-") as work:
        song_seconds = 0.0 if audio_path is None else n_frames / fps
        cmd = ["ffmpeg", "-y", "-hide_banner", "-loglevel", "error", "-nostdin"]
        cmd += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{size[0]}x{size[1]}", "-framerate", f"{fps}"]
        cmd += ["-i", "pipe:0"]
        if audio_path is not None:
            wave, rate_hz = load_audio(audio_path, sample_rate=None, mono=False)
            wav = Path(work) / "audio.wav"
            # The music under the motion only: N / fps seconds from the start of the song.
            sf.write(wav, wave[:, : round(n_frames / fps * rate_hz)].T, rate_hz, subtype="FLOAT")
            cmd += ["-i", str(wav), "-map", "0:v:0", "-map", "1:a:0", "-c:a", "aac", "-b:a", AUDIO_BITRATE]
        # The video gets exactly the frames written to the pipe (``-frames:v`` would stop the audio early).
        cmd += ["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-pix_fmt", "yuv420p"]
        cmd += ["-movflags", "+faststart", "-f", "mp4", str(tmp)]
        log_path = Path(work) / "ffmpeg.log"
        with open(log_path, "wb") as log:
            # stdin=PIPE: frames are streamed; its own session, so a timeout kills ffmpeg and anything it started.
            proc = subprocess.Popen(
                cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log, start_new_session=os.name == "posix"
            )
            assert proc.stdin is not None
            watchdog = _Watchdog(proc, stall_seconds)
            watchdog.deadline = math.inf  # drawing a frame is our time, not ffmpeg's: only writes can stall
            try:
                for frame in frames:
                    watchdog.deadline = time.monotonic() + stall_seconds
                    proc.stdin.write(frame.tobytes())
                    watchdog.deadline = math.inf
                # the encode's end waits at most until a request's time limit (dgsdp.utils.deadline)
                watchdog.deadline = time.monotonic() + min(stall_seconds + song_seconds, max(seconds_left(), 0.0))
                proc.stdin.close()
            except (BrokenPipeError, OSError):
                pass  # ffmpeg stopped early (or was killed); its log or the watchdog says why
            except BaseException:
                _kill(proc)
                proc.wait()
                watchdog.stop()
                raise
            code = proc.wait()
            watchdog.stop()
        if watchdog.fired:
            check_time()  # stopped at the request's time limit: say so, not that ffmpeg stalled
            raise DgsdpError(
                f"ffmpeg stopped responding while writing the video"
                f"{'' if audio_path is None else f' for {audio_path}'} and was stopped after {stall_seconds:g} s "
                "without progress (set DGSDP_FFMPEG_TIMEOUT=<seconds> to wait longer). "
                "Try another version of the song (e.g. re-encode it to 16-bit wav), or leave out the video "
                "(formats without 'video')."
            )
        if code != 0:
            message = log_path.read_text(errors="replace").strip()[-2000:]
            raise DgsdpError(
                f"ffmpeg failed (exit code {code}) while writing the video: {message or 'no message'}. "
                "Check that your ffmpeg has the libx264 and aac encoders (`ffmpeg -encoders`)."
            )


def render_video(
    path: str | os.PathLike,
    joints: torch.Tensor | np.ndarray,
    fps: float = 30,
    audio_path: str | os.PathLike | None = None,
    title: str | None = None,
    size: tuple[int, int] = (480, 480),
    camera: Camera | None = None,
    azimuth_deg: float = 20.0,
    elevation_deg: float = 15.0,
    floor_z: float = 0.0,
    skeleton: Skeleton = SMPL24,
) -> Path:
    """Render joints (T, J, 3) of ``skeleton``, z-up metres at ``fps``, as a stick-figure video of T frames, its
    floor grid at height ``floor_z`` (the run's floor); returns the path.

    With ffmpeg: an mp4 (H.264, yuv420p) with the music at ``audio_path`` cut to the motion's duration and muxed
    as AAC (see the module docstring). Without ffmpeg, or when ``path`` ends in ``.gif``: a silent GIF next to
    ``path`` (with a warning when ffmpeg is missing). ``camera``: a fixed view; by default the camera follows the
    dancer (``follow_cameras``), seen from ``azimuth_deg`` and ``elevation_deg`` (see ``Camera``). The file appears atomically (no half-written video on error).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in ("", ".mp4", ".gif"):
        raise ConfigError(f"videos are written as .mp4 (or .gif without ffmpeg); got {path.name!r}")
    if not fps > 0:
        raise ConfigError(f"fps must be positive, got {fps}")
    motion = _as_joints(joints, skeleton)
    if motion.ndim != 3:
        raise DataError(f"render_video needs a motion (T, {skeleton.num_joints}, 3), got shape {motion.shape}")
    size = _check_size(size)
    if not math.isfinite(floor_z):
        raise ConfigError(f"the floor height must be a finite number of metres, got {floor_z}")
    if camera is not None:
        cameras = [camera] * len(motion)
    else:
        cameras = follow_cameras(motion, fps, azimuth_deg, elevation_deg, floor_z=floor_z)
    frames = _frames(motion, cameras, size, title, skeleton)

    if suffix == ".gif" or not ffmpeg_available():
        if suffix != ".gif":
            warnings.warn(
                "ffmpeg was not found on PATH: writing a GIF without audio instead of an mp4. "
                "Install ffmpeg (e.g. `apt install ffmpeg` or `conda install ffmpeg`) for mp4 with music.",
                stacklevel=2,
            )
        out = path.with_suffix(".gif")
        with atomic_path(out) as tmp:
            _write_gif(tmp, frames, fps)
        return out

    out = path.with_suffix(".mp4")
    audio = Path(audio_path) if audio_path is not None else None
    with atomic_path(out) as tmp:
        _write_mp4(tmp, frames, len(motion), fps, size, audio)
    return out
