"""Stick-figure rendering: pixels where the projected joints are, the floor at z = 0, titles that fit, a camera
that follows the dancer, mp4 with one frame per motion frame and the song from time 0 (ffprobe), GIF fallback."""

import json
import shutil
import subprocess
import time

import numpy as np
import pytest
import soundfile as sf
import torch
from PIL import Image

import dgsdp.export.render as render
from dgsdp.errors import AudioError, ConfigError, DataError
from dgsdp.export import Camera, ffmpeg_available, render_frame, render_video
from dgsdp.motion import axis_angle_to_matrix, forward_kinematics, root_rotation_y_up_to_z_up
from dgsdp.utils.deadline import TimeLimitError, time_limit

WHITE = np.array([255, 255, 255])


def standing_pose(left_arm_down: float = 0.0) -> torch.Tensor:
    """(24, 3) z-up joints of the upright rest pose, pelvis 0.9 m above the floor; optionally the left arm
    lowered by ``left_arm_down`` radians at the shoulder."""
    rot = torch.eye(3).repeat(24, 1, 1)
    rot[0] = root_rotation_y_up_to_z_up(rot[0])
    rot[16] = axis_angle_to_matrix(torch.tensor([0.0, 0.0, -left_arm_down]))
    return forward_kinematics(rot, torch.tensor([0.0, 0.0, 0.9]))


def dancing(frames: int) -> torch.Tensor:
    """(T, 24, 3) z-up joints: an upright body swinging its arms while walking along x."""
    t = torch.arange(frames, dtype=torch.float32)
    rot = torch.eye(3).repeat(frames, 24, 1, 1)
    rot[:, 0] = root_rotation_y_up_to_z_up(rot[:, 0])
    swing = torch.stack((torch.zeros(frames), torch.zeros(frames), -0.2 - torch.sin(t / 3)), dim=-1)
    rot[:, 16] = axis_angle_to_matrix(swing)
    rot[:, 17] = axis_angle_to_matrix(-swing)
    trans = torch.stack((0.02 * t, torch.zeros(frames), torch.full((frames,), 0.9)), dim=-1)
    return forward_kinematics(rot, trans)


def sine_wav(path, seconds: float, rate_hz: int = 22050):
    n = int(round(seconds * rate_hz))
    sf.write(path, 0.3 * np.sin(2 * np.pi * 440 * np.arange(n) / rate_hz).astype(np.float32), rate_hz)
    return path


def front_pixel(point: np.ndarray, target, extent_m: float, size) -> tuple[int, int]:
    """Orthographic front view (azimuth 0, elevation 0) by hand: screen right = +x, screen up = +z."""
    w, h = size
    s = min(w, h) / extent_m
    return int(round(w / 2 + s * (point[0] - target[0]))), int(round(h / 2 - s * (point[2] - target[2])))


def test_frame_pixels_follow_projected_joints():
    size = (200, 160)  # W != H catches swapped axes
    cam = Camera(target=(0.0, 0.0, 0.9), extent_m=2.5, azimuth_deg=0.0, elevation_deg=0.0, floor_z=-10.0)
    pose = standing_pose().numpy()
    img = render_frame(pose, cam, size=size)
    assert img.shape == (160, 200, 3) and img.dtype == np.uint8

    for j in (15, 20, 21, 10, 0):  # head, wrists, a toe, pelvis
        x, y = front_pixel(pose[j], cam.target, cam.extent_m, size)
        patch = img[y - 1 : y + 2, x - 1 : x + 2].reshape(-1, 3)
        assert (patch != WHITE).any(axis=1).all(), f"joint {j} not drawn at ({x}, {y})"
    # Everything drawn lies in the projected joints' bounding box grown by the head circle and line width.
    px = np.array([front_pixel(p, cam.target, cam.extent_m, size) for p in pose])
    grow = 0.09 * min(size) / cam.extent_m + 4
    ys, xs = np.nonzero((img != WHITE).any(axis=-1))
    assert xs.min() >= px[:, 0].min() - grow and xs.max() <= px[:, 0].max() + grow
    assert ys.min() >= px[:, 1].min() - grow and ys.max() <= px[:, 1].max() + grow
    assert (img[0, 0] == WHITE).all() and (img[-1, -1] == WHITE).all()


def test_camera_axes_hand_worked():
    size = (100, 100)
    side = Camera(target=(0.0, 0.0, 0.0), extent_m=2.0, azimuth_deg=90.0, elevation_deg=0.0)
    # Seen from +x, +y is to the right and +x points at the viewer (no screen motion).
    np.testing.assert_allclose(side.project(np.array([0.0, 0.5, 0.25]), size), [75.0, 37.5], atol=1e-9)
    np.testing.assert_allclose(side.project(np.array([0.7, 0.0, 0.0]), size), [50.0, 50.0], atol=1e-9)
    top = Camera(target=(0.0, 0.0, 0.0), extent_m=2.0, azimuth_deg=0.0, elevation_deg=90.0)
    # Straight down with azimuth 0: +x right, +y up on screen.
    np.testing.assert_allclose(top.project(np.array([0.5, 0.5, 3.0]), size), [75.0, 25.0], atol=1e-9)


def test_fitted_camera_keeps_the_dance_in_view():
    joints = dancing(40).numpy()
    joints[:, :, 0] += 3.0  # far from the origin, travelling
    size = (120, 90)
    cam = render.fit_camera(joints, azimuth_deg=35.0, elevation_deg=25.0, margin=0.1)
    px = cam.project(joints, size)
    assert (px >= 0).all() and (px[..., 0] <= size[0]).all() and (px[..., 1] <= size[1]).all()
    # Centred: the on-screen box of all joints has its middle at the image centre.
    box_middle = (px.reshape(-1, 2).min(0) + px.reshape(-1, 2).max(0)) / 2
    np.testing.assert_allclose(box_middle, [60.0, 45.0], atol=1e-6)
    assert cam.floor_z == 0.0  # the true floor, not the lowest joint


def test_frames_differ_and_title():
    cam = render.fit_camera(standing_pose())
    a = render_frame(standing_pose(), cam, size=(96, 96))
    b = render_frame(standing_pose(left_arm_down=1.2), cam, size=(96, 96))
    assert (a != b).any(axis=-1).sum() > 20
    titled = render_frame(standing_pose(), cam, size=(96, 96), title="gBR")
    assert (titled[:20] != a[:20]).any()


def test_bad_inputs(tmp_path):
    with pytest.raises(DataError, match="24, 3"):
        render_frame(np.zeros((23, 3)))
    with pytest.raises(ConfigError, match=".mp4"):
        render_video(tmp_path / "a.avi", dancing(4))


def ffprobe_streams(path) -> list[dict]:
    out = subprocess.run(
        ["ffprobe", "-v", "error", "-show_entries", "stream=codec_type,codec_name,pix_fmt,duration,nb_frames",
         "-of", "json", str(path)],
        check=True, capture_output=True, text=True,
    ).stdout  # fmt: skip
    return json.loads(out)["streams"]


needs_ffmpeg = pytest.mark.skipif(
    not (ffmpeg_available() and shutil.which("ffprobe")), reason="ffmpeg/ffprobe not installed"
)


@needs_ffmpeg
def test_mp4_with_song(tmp_path):
    song = sine_wav(tmp_path / "song.wav", 2.0)
    out = render_video(tmp_path / "dance.mp4", dancing(60), fps=30, audio_path=song, title="test", size=(96, 96))
    assert out == tmp_path / "dance.mp4" and out.is_file()
    streams = {s["codec_type"]: s for s in ffprobe_streams(out)}
    assert streams["video"]["codec_name"] == "h264" and streams["video"]["pix_fmt"] == "yuv420p"
    assert int(streams["video"]["nb_frames"]) == 60
    assert streams["audio"]["codec_name"] == "aac"
    assert float(streams["audio"]["duration"]) == pytest.approx(2.0, abs=0.05)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dance.mp4", "song.wav"]


def counted_frames(path) -> tuple[int, dict]:
    """Video frames decoded by ffprobe (-count_frames) and the start times of the streams."""
    out = subprocess.run(
        ["ffprobe", "-v", "error", "-count_frames", "-show_entries", "stream=codec_type,nb_read_frames,start_time",
         "-of", "json", str(path)],
        check=True, capture_output=True, text=True,
    ).stdout  # fmt: skip
    streams = {s["codec_type"]: s for s in json.loads(out)["streams"]}
    return int(streams["video"]["nb_read_frames"]), {k: float(v["start_time"]) for k, v in streams.items()}


@needs_ffmpeg
@pytest.mark.parametrize(
    ("song_seconds", "rate_hz", "frames"),
    [
        (3.0, 22050, 30),  # song much longer than the motion: the video still ends with the motion
        (2.345, 44100, 70),  # a song whose length is not a whole number of frames: floor(2.345 * 30) = 70
        (1.0, 48000, 30),
        (0.5, 22050, 29),  # song shorter than the motion
    ],
)
def test_mp4_has_one_frame_per_motion_frame(tmp_path, song_seconds, rate_hz, frames):
    song = sine_wav(tmp_path / "song.wav", song_seconds, rate_hz)
    out = render_video(tmp_path / "dance", dancing(frames), fps=30, audio_path=song, size=(64, 48))
    assert out.suffix == ".mp4"
    n, starts = counted_frames(out)
    assert n == frames
    assert starts["video"] == pytest.approx(0.0, abs=1e-3) and starts["audio"] == pytest.approx(0.0, abs=1e-3)
    audio = {s["codec_type"]: s for s in ffprobe_streams(out)}["audio"]
    assert float(audio["duration"]) == pytest.approx(min(song_seconds, frames / 30), abs=0.03)


@needs_ffmpeg
def test_mp4_from_a_compressed_song(tmp_path):
    """An mp3 (its decoder adds samples at the start); the motion covers floor(duration * 30) frames."""
    wav = sine_wav(tmp_path / "song.wav", 2.71, 44100)
    mp3 = tmp_path / "song.mp3"
    subprocess.run(["ffmpeg", "-v", "error", "-i", str(wav), str(mp3)], check=True)
    from dgsdp.audio.io import load_audio

    wave, rate_hz = load_audio(mp3, sample_rate=None)
    frames = len(wave) * 30 // rate_hz
    out = render_video(tmp_path / "dance.mp4", dancing(frames), fps=30, audio_path=mp3, size=(64, 48))
    assert counted_frames(out)[0] == frames


@needs_ffmpeg
def test_missing_song_leaves_no_file(tmp_path):
    with pytest.raises(AudioError, match="not found"):
        render_video(tmp_path / "dance.mp4", dancing(10), audio_path=tmp_path / "nope.wav", size=(64, 64))
    assert not any(tmp_path.iterdir())


def test_gif_fallback_without_ffmpeg(tmp_path, monkeypatch):
    monkeypatch.setattr(render, "ffmpeg_available", lambda: False)
    song = sine_wav(tmp_path / "song.wav", 0.5)
    with pytest.warns(UserWarning, match="ffmpeg"):
        out = render_video(tmp_path / "dance.mp4", dancing(12), fps=30, audio_path=song, size=(64, 64))
    assert out == tmp_path / "dance.gif"
    with Image.open(out) as gif:
        assert gif.format == "GIF" and gif.n_frames == 12 and gif.size == (64, 64)
        assert gif.info["duration"] == pytest.approx(1000 / 30, abs=10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dance.gif", "song.wav"]


# The floor: drawn at the run's floor (z = 0 for the synthetic data), not at the lowest joint.


def lifted(height_m: float) -> np.ndarray:
    """The standing pose with its pelvis ``height_m`` above the floor (lowest joint well above z = 0)."""
    pose = standing_pose().numpy()
    pose[:, 2] += height_m - 0.9
    return pose


def is_floor(pixel: np.ndarray) -> bool:
    return bool(np.abs(pixel.astype(int) - render.FLOOR_COLOUR).max() <= 2)


def test_floor_line_at_true_height_front_view():
    size = (200, 200)
    pose = lifted(2.0)
    cam = Camera(target=(0.0, 0.0, 1.0), extent_m=3.5, azimuth_deg=0.0, elevation_deg=0.0)
    img = render_frame(pose, cam, size=size)
    scale = 200 / 3.5
    floor_row = round(100 + scale * 1.0)  # z = 0 seen edge-on: one horizontal line
    rows = [r for r in range(200) if np.mean([is_floor(p) for p in img[r]]) > 0.9]
    assert rows and min(rows) >= floor_row - 1 and max(rows) <= floor_row + 1
    lowest_row = round(100 - scale * (pose[:, 2].min() - 1.0))
    assert floor_row - lowest_row > 40  # far from where a lowest-joint floor would be


def grid_crossings(camera: Camera, n: int = 2) -> np.ndarray:
    """Floor grid crossings (z = 0) around the camera's target, (K, 3)."""
    step = render.GRID_STEP_M
    cx, cy = round(camera.target[0] / step) * step, round(camera.target[1] / step) * step
    return np.array([(cx + i * step, cy + k * step, 0.0) for i in range(-n, n + 1) for k in range(-n, n + 1)])


def test_floor_grid_at_true_height_oblique_view():
    size = (240, 240)
    pose = lifted(2.2)
    cam = render.fit_camera(pose, azimuth_deg=30.0, elevation_deg=30.0)
    cam = Camera((cam.target[0], cam.target[1], 1.0), 4.0, 30.0, 30.0)  # zoomed out to see the floor
    img = render_frame(pose, cam, size=size)
    lowest = pose[:, 2].min()
    drawn = shifted = 0
    for point in grid_crossings(cam):
        x, y = np.round(cam.project(point, size)).astype(int)
        x2, y2 = np.round(cam.project(point + [0, 0, lowest], size)).astype(int)
        if 2 <= x < 238 and 2 <= y < 238 and 2 <= x2 < 238 and 2 <= y2 < 238:
            drawn += is_floor(img[y, x])
            shifted += (img[y2 - 1 : y2 + 2, x2 - 1 : x2 + 2] == 255).all(axis=-1).all()
    assert drawn >= 5 and shifted >= 5  # grid crossings at z = 0 are drawn; at the lowest joint's height, nothing


@needs_ffmpeg
@pytest.mark.parametrize("floor_z", [0.0, 0.6])
def test_video_frames_show_the_floor_at_true_height(tmp_path, floor_z):
    """Through the whole mp4 path, following camera: a front view (the floor seen edge-on, one line) of a dance
    0.8 m above the floor, the run's floor at ``floor_z``."""
    joints = dancing(20).numpy()
    joints[..., 2] += 0.8 + floor_z
    size = (240, 240)
    out = render_video(
        tmp_path / "dance.mp4", joints, fps=30, size=size, azimuth_deg=0.0, elevation_deg=0.0, floor_z=floor_z
    )
    raw = subprocess.run(
        ["ffmpeg", "-v", "error", "-i", str(out), "-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"],
        check=True, capture_output=True,
    ).stdout  # fmt: skip
    frames = np.frombuffer(raw, np.uint8).reshape(-1, 240, 240, 3).astype(int)
    assert len(frames) == 20
    cameras = render.follow_cameras(joints, fps=30, azimuth_deg=0.0, elevation_deg=0.0, floor_z=floor_z)
    for t in (0, 10, 19):
        # Front view by hand: screen up is +z, the target's height at the image centre.
        scale, target_z = 240 / cameras[t].extent_m, cameras[t].target[2]
        floor_row = round(120 + scale * (target_z - floor_z))
        lowest_row = round(120 - scale * (joints[t, :, 2].min() - target_z))
        grey_rows = [r for r in range(240) if np.mean(np.abs(frames[t, r] - 200).max(axis=-1) < 20) > 0.8]
        assert grey_rows and min(grey_rows) >= floor_row - 2 and max(grey_rows) <= floor_row + 2, (t, grey_rows)
        assert floor_row - lowest_row > 25
        # Below the feet and above the floor: only white.
        assert frames[t, lowest_row + 5 : floor_row - 5].min() > 235


# The camera follows the dancer.


def test_camera_follows_a_travelling_dancer():
    joints = dancing(150).numpy()
    joints[..., 0] += 0.03 * np.arange(150)[:, None]  # 0.05 m per frame along x in all: 7.5 m
    size = (160, 120)
    cameras = render.follow_cameras(joints, fps=30)
    assert len(cameras) == 150
    assert len({c.extent_m for c in cameras}) == 1 and len({c.target[2] for c in cameras}) == 1
    assert all(c.floor_z == 0.0 for c in cameras)
    for t in range(150):
        px = cameras[t].project(joints[t], size)
        assert (px >= 0).all() and (px[:, 0] <= size[0]).all() and (px[:, 1] <= size[1]).all(), t
        assert abs(px[0, 0] - size[0] / 2) < 0.1 * size[0], t  # pelvis near the middle
    # A fixed camera fitted to the whole path would show the dancer at a third of the size or less.
    assert cameras[0].extent_m < render.fit_camera(joints).extent_m / 3


def test_camera_smooths_root_jitter():
    joints = np.repeat(standing_pose().numpy()[None], 90, axis=0)
    jitter = 0.05 * (-1.0) ** np.arange(90)  # 5 cm left-right every frame
    joints[..., 0] += jitter[:, None]
    targets = np.array([c.target for c in render.follow_cameras(joints, fps=30)])
    assert np.abs(np.diff(targets[:, 0])).max() < 0.002  # the camera barely moves
    assert np.abs(targets[30:60, 0]).max() < 0.1 * 0.05  # and stays on the mean position (away from the ends)


# Titles fit the frame.

LONG_TITLE = "gBR_sBM_cAll_d04_mBR0_ch01 - style: slow graceful moonwalk with sharp arm waves, then a spin"


def test_long_title_is_wrapped_within_the_width():
    width = 150
    lines, font = render.fit_title(LONG_TITLE, width, 20)
    assert len(lines) > 1 and " ".join(lines) == LONG_TITLE  # wrapped at spaces, nothing lost
    assert all(font.getlength(line) <= width for line in lines)
    assert len(lines) <= render.TITLE_MAX_LINES
    short_lines, short_font = render.fit_title("gBR", width, 20)
    assert short_lines == ["gBR"] and short_font.size == 20
    cut, small = render.fit_title("x" * 400, width, 20)
    assert cut[0].endswith("...") and small.getlength(cut[0]) <= width


def test_long_title_pixels_stay_inside_the_frame():
    size = (160, 160)
    cam = Camera(target=(0.0, 0.0, 0.9), extent_m=6.0, azimuth_deg=0.0, elevation_deg=0.0, floor_z=-10.0)
    img = render_frame(standing_pose(), cam, size=size, title=LONG_TITLE)
    ink = (img < 40).all(axis=-1)  # black text; the figure's colours are lighter
    line_px = max(1, round(160 / 120))
    margin = line_px * 4
    assert ink.sum() > 200
    assert not ink[:, -margin + 1 :].any()  # no text runs into the right margin (or off the image)
    rows = np.nonzero(ink.any(axis=1))[0]
    assert rows.max() - rows.min() > 20  # more than one line


def test_a_long_title_is_fitted_once_per_video_and_a_huge_one_quickly(tmp_path, monkeypatch):
    fitted = []
    fit = render.fit_title
    monkeypatch.setattr(render, "fit_title", lambda *args: fitted.append(args[0]) or fit(*args))
    title = " ".join(["sharp powerful krump"] * 50)[:1000]
    out = render_video(tmp_path / "dance.gif", dancing(8), fps=30, title=title, size=(96, 96))
    assert out.is_file() and fitted == [title]  # once for the 8 frames
    for huge in (" ".join(["krump"] * 20_000), "x" * 100_000):  # 100 KB with spaces, and one long word
        started = time.perf_counter()
        lines, font = fit(huge, 448, 20)
        assert time.perf_counter() - started < 1.0
        assert len(lines) == render.TITLE_MAX_LINES if " " in huge else len(lines) == 1
        assert lines[-1].endswith("...") and all(font.getlength(line) <= 448 for line in lines)


@pytest.mark.skipif(not ffmpeg_available(), reason="ffmpeg not installed")
def test_slow_frames_are_not_taken_for_a_stalled_ffmpeg(tmp_path, monkeypatch):
    """The watchdog counts the time ffmpeg takes to accept a frame, not the time spent drawing it."""
    monkeypatch.setenv("DGSDP_FFMPEG_TIMEOUT", "0.5")
    draw = render._draw_frame

    def slow(*args):
        time.sleep(0.8)
        return draw(*args)

    monkeypatch.setattr(render, "_draw_frame", slow)
    out = render_video(tmp_path / "dance.mp4", dancing(3), fps=30, size=(64, 64))
    assert counted_frames(out)[0] == 3


def test_the_video_stops_at_a_time_limit_and_leaves_no_file(tmp_path):
    with time_limit(0.2, "stopped: the request's time limit"), pytest.raises(TimeLimitError, match="time limit"):
        render_video(tmp_path / "dance.gif", dancing(2000), fps=30, size=(64, 64))
    assert not any(tmp_path.iterdir())
