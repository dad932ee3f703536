"""Stick-figure rendering: pixels where the projected joints are, mp4 with the song (ffprobe), GIF fallback."""

import json
import shutil
import subprocess

import numpy as np
import pytest
import soundfile as sf
import torch
from PIL import Image

import dgsdp.export.render as render
from dgsdp.errors import AudioError, ConfigError, DataError
from dgsdp.export import Camera, ffmpeg_available, render_frame, render_video
from dgsdp.motion import axis_angle_to_matrix, forward_kinematics, root_rotation_y_up_to_z_up

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
    assert cam.floor_z == pytest.approx(joints[..., 2].min())


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


@needs_ffmpeg
def test_mp4_song_longer_than_motion_holds_last_frame(tmp_path):
    song = sine_wav(tmp_path / "song.wav", 3.0)
    out = render_video(tmp_path / "dance", dancing(30), fps=30, audio_path=song, size=(64, 48))
    assert out.suffix == ".mp4"
    streams = {s["codec_type"]: s for s in ffprobe_streams(out)}
    assert float(streams["audio"]["duration"]) == pytest.approx(3.0, abs=0.05)
    assert int(streams["video"]["nb_frames"]) == 90


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
