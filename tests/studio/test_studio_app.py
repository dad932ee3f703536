"""The studio's handlers without a browser: timeline to schedule, edits mapped to editing tasks, errors, folders."""

import json
import os
import re

import numpy as np
import pytest
import soundfile as sf
import torch

pytest.importorskip("gradio", reason="the studio needs Gradio: pip install -e '.[studio]'")

import gradio as gr  # noqa: E402

from dgsdp.errors import ConfigError  # noqa: E402
from dgsdp.generation import parse_schedule  # noqa: E402
from dgsdp.motion import LOWER_BODY_JOINTS, UPPER_BODY_JOINTS, channels_for_joints  # noqa: E402
from dgsdp.studio import engine as eng  # noqa: E402
from dgsdp.studio.app import (  # noqa: E402
    EDIT_LABELS,
    Studio,
    StudioConfig,
    build_app,
    find_checkpoints,
    parse_args,
    schedule_text,
    style_text,
)


def no_progress(*args, **kwargs) -> None:
    return None


def test_timeline_rows_become_a_schedule_the_pipeline_parses():
    rows = [[0, "10", "krump"], [10, "20.5", 'a slow "jazz" ballet'], [None, None, None], [20.5, "end", "house"]]
    text = schedule_text(rows)
    assert text == '0-10: "krump"; 10-20.5: \'a slow "jazz" ballet\'; 20.5-end: "house"'
    spans = parse_schedule(text)
    assert [(s.start_s, s.end_s, s.style) for s in spans] == [
        (0, 10, "krump"), (10, 20.5, 'a slow "jazz" ballet'), (20.5, float("inf"), "house"),
    ]  # fmt: skip
    assert schedule_text([]) == "" and schedule_text(None) == ""
    # the timeline wins over free text, free text over the genre
    assert style_text("Break", "smooth waacking", rows) == text
    assert style_text("Break", "smooth waacking", []) == "smooth waacking"
    assert style_text("Break", "  ", []) == "Break"
    for bad, message in (([[0, "5", ""]], "has no style"), ([[5, "2", "krump"]], "end after it starts"),
                         ([["a", "2", "krump"]], "times are seconds")):  # fmt: skip
        with pytest.raises(ConfigError, match=message):
            schedule_text(bad)


def test_edits_map_to_the_editing_tasks():
    motion = torch.randn(90, 151)
    upper = eng.edit_settings(eng.Edit("upper_body", motion), 90, 30)
    assert upper.task == "upper_body" and upper.motion is not None and len(upper.motion) == 90
    assert eng.edit_settings(eng.Edit("lower_body", motion), 90, 30).task == "lower_body"
    keys = eng.edit_settings(eng.Edit("keyframes", motion, keyframe_seconds=[0.5, 2]), 90, 30)
    assert keys.task == "keyframes" and list(keys.keyframe_seconds) == [0.5, 2]
    cont = eng.edit_settings(eng.Edit("continue", motion, seed_seconds=0.5), 60, 30)
    assert cont.task == "seed_motion" and cont.seed_frames == 15
    assert torch.equal(cont.motion, motion[-15:])  # the new dance starts where the current one ends
    span = eng.edit_settings(eng.Edit("range", motion, start_seconds=1, end_seconds=2), 90, 30)
    assert span.task == "keyframes" and span.keyframes == list(range(30)) + list(range(60, 90))
    assert eng.edit_settings(None, 90, 30).task == "none"
    with pytest.raises(ConfigError, match="inside the song"):
        eng.edit_settings(eng.Edit("range", motion, start_seconds=2, end_seconds=1), 90, 30)
    with pytest.raises(ConfigError, match="covers the whole dance"):
        eng.edit_settings(eng.Edit("range", motion, start_seconds=0, end_seconds=3), 90, 30)
    with pytest.raises(ConfigError, match="keyframe times"):
        eng.edit_settings(eng.Edit("keyframes", motion), 90, 30)
    with pytest.raises(ConfigError, match="edits keep the current dance's song"):
        eng.edit_settings(eng.Edit("upper_body", motion), 120, 30)
    assert eng.parse_seconds("1.5, 4 ;8") == [1.5, 4.0, 8.0]
    with pytest.raises(ConfigError, match="'x' is not a time"):
        eng.parse_seconds("1, x")


def test_command_line_defaults_to_this_machine_only(tmp_path):
    config = parse_args([])
    assert (config.host, config.port) == ("127.0.0.1", 7860)
    config = parse_args(["--checkpoint", "m.ckpt", "--host", "0.0.0.0", "--port", "9000", "--max-seconds", "60"])
    assert (config.checkpoint, config.host, config.port, config.max_song_seconds) == ("m.ckpt", "0.0.0.0", 9000, 60)
    old, new = tmp_path / "a" / "checkpoints" / "last.ckpt", tmp_path / "b" / "c" / "checkpoints" / "last.ckpt"
    for i, p in enumerate((old, new)):
        p.parent.mkdir(parents=True)
        p.write_bytes(b"x")
        os.utime(p, (1000 + i, 1000 + i))
    (tmp_path / "a" / "checkpoints" / "epoch=1.ckpt").write_bytes(b"x")
    assert find_checkpoints(tmp_path) == [str(new), str(old)]
    assert find_checkpoints(tmp_path / "missing") == []


@pytest.fixture(scope="module")
def studio(studio_checkpoint, tmp_path_factory) -> Studio:
    work = tmp_path_factory.mktemp("studio_app")
    config = StudioConfig(checkpoint=studio_checkpoint, work_dir=str(work), outputs=str(work / "none"),
                          max_song_seconds=20, max_upload_mb=2, device="cpu",
                          allow_checkpoint_paths=True)  # fmt: skip
    demo, studio = build_app(config)
    assert isinstance(demo, gr.Blocks)
    return studio


def settings(studio, **overrides):
    values = {"checkpoint": studio.config.checkpoint, "genre": "Krump", "free_text": "", "rows": [],
              "music_w": 1.0, "style_w": 1.0, "sampler": "ddim", "steps": 2, "seed": 0, "video": False}  # fmt: skip
    values.update(overrides)
    return list(values.values())


def test_generate_then_edit_through_the_pipeline(studio, studio_songs):
    value, files, state, status = studio.on_generate(str(studio_songs["three"]), *settings(studio),
                                                     progress=no_progress)  # fmt: skip
    suffixes = {f.rsplit(".", 1)[1] for f in files}
    assert {"pkl", "bvh", "npy"} <= suffixes and "mp4" not in suffixes
    assert ("glb" in suffixes) == eng.glb_available()
    base = np.load(state["motion"])
    assert base.shape == (90, 151)
    viewer = json.loads(value)
    assert viewer["frames"] == 90 and viewer["audio_url"].endswith("three.wav")
    joints_file = viewer["motion_url"].split("file=", 1)[1]
    data = json.loads(open(joints_file).read())
    assert data["n_frames"] == 90 and len(data["joints_mm"]) == 90 * 24 * 3
    assert "90 frames (3.0 s)" in status and "the song:" not in status  # 120 BPM: given as it is

    lower = channels_for_joints(list(LOWER_BODY_JOINTS), with_root_and_contacts=True)
    upper = channels_for_joints(list(UPPER_BODY_JOINTS), with_root_and_contacts=False)

    def edit(label, **kw):
        args = {"keyframe_text": "", "seed_seconds": 1.0, "range_start": 0.0, "range_end": 0.0, **kw}
        out = studio.on_edit(state, str(studio_songs["two"]), *settings(studio, seed=1), label, *args.values(),
                             progress=no_progress)  # fmt: skip
        return np.load(out[2]["motion"]), out[2]

    label = {v: k for k, v in EDIT_LABELS.items()}
    new, new_state = edit(label["upper_body"])
    assert new.shape == (90, 151) and new_state["motion"] != state["motion"]
    np.testing.assert_allclose(new[:, lower], base[:, lower], atol=1e-4)  # the lower body is kept
    assert np.abs(new[:, upper] - base[:, upper]).max() > 1e-2  # the upper body is new

    new, _ = edit(label["lower_body"])
    np.testing.assert_allclose(new[:, upper], base[:, upper], atol=1e-4)
    assert np.abs(new[:, lower] - base[:, lower]).max() > 1e-2

    new, _ = edit(label["keyframes"], keyframe_text="0.5, 2")
    np.testing.assert_allclose(new[[15, 60]], base[[15, 60]], atol=1e-4)
    assert np.abs(new[30] - base[30]).max() > 1e-2

    new, _ = edit(label["range"], range_start=1.0, range_end=2.0)
    np.testing.assert_allclose(new[:30], base[:30], atol=1e-4)
    np.testing.assert_allclose(new[60:], base[60:], atol=1e-4)
    assert np.abs(new[30:60] - base[30:60]).max() > 1e-2

    new, cont_state = edit(label["continue"], seed_seconds=0.5)  # on to the 2 s song in the upload box
    assert new.shape == (60, 151) and cont_state["song"].endswith("two.wav")
    np.testing.assert_allclose(new[:15], base[-15:], atol=1e-4)


def test_status_says_when_a_fast_song_was_given_in_half_time(studio, tmp_path):
    from generation.gen_helpers import write_click_song

    fast = tmp_path / "fast_mBR9.wav"  # 170 BPM; the tiny checkpoint was trained on 80-100 BPM
    write_click_song(fast, 3.0, bpm=170.0)
    status = studio.on_generate(str(fast), *settings(studio), progress=no_progress)[3]
    assert "; the song: " in status and "given in half time" in status and "trained on 80-100 BPM" in status
    assert "; beat sync: " in status  # which timing beat sync kept (docs/beatsync.md)


def test_errors_are_one_clear_message(studio, studio_songs, tmp_path):
    def generate(song, **kw):
        return studio.on_generate(song, *settings(studio, **kw), progress=no_progress)

    cases = [
        (None, {}, "upload a song"),
        (str(studio_songs["broken"]), {}, "Cannot decode audio file"),
        (
            str(studio_songs["long"]),
            {},
            "30 s long; this studio takes songs up to 20 s \\(its --max-seconds setting\\)",
        ),
        (str(studio_songs["three"]), {"checkpoint": str(tmp_path / "none.ckpt")}, "does not exist"),
        (str(studio_songs["three"]), {"genre": "", "free_text": ""}, "this model is conditioned on style"),
        (str(studio_songs["three"]), {"rows": [[0, "x", "krump"]]}, "times are seconds"),
    ]
    notes = tmp_path / "notes.txt"
    notes.write_text("not a song")
    cases.append((str(notes), {}, "upload a wav, mp3, ogg or flac"))
    big = tmp_path / "big.wav"
    big.write_bytes(b"\0" * (3 * 2**20))
    cases.append((str(big), {}, "the limit is 2 MB"))
    bad_ckpt = tmp_path / "bad.ckpt"
    bad_ckpt.write_bytes(b"not a checkpoint")
    cases.append((str(studio_songs["three"]), {"checkpoint": str(bad_ckpt)}, "cannot read checkpoint"))
    runs_before = sorted((studio.work_dir / "runs").glob("*")) if (studio.work_dir / "runs").exists() else []
    for song, kw, message in cases:
        with pytest.raises(gr.Error, match=message):
            generate(song, **kw)
    runs_after = sorted((studio.work_dir / "runs").glob("*")) if (studio.work_dir / "runs").exists() else []
    assert runs_after == runs_before  # a failed request leaves no folder behind
    with pytest.raises(gr.Error, match="generate a dance first"):
        studio.on_edit(None, None, *settings(studio), next(iter(EDIT_LABELS)), "", 1.0, 0.0, 0.0,
                       progress=no_progress)  # fmt: skip


def test_example_songs_are_synthesised_locally(studio):
    path = studio.on_example("Krump")
    assert path.endswith("example_KR.wav")
    info = sf.info(path)
    assert abs(info.frames / info.samplerate - 10.0) < 1e-3


def test_timeline_bar_draws_the_spans_along_the_song(studio, studio_songs):
    text, bar = studio.on_timeline([[0, "1", "krump"], [1, "end", "house"]], str(studio_songs["three"]))
    assert text == '0-1: "krump"; 1-end: "house"'
    widths = [float(w) for w in re.findall(r"width:([\d.]+)%", bar)]
    assert widths == pytest.approx([100 / 3, 200 / 3], abs=0.01)  # 1 s and 2 s of a 3 s song
    assert "0-1 s: krump" in bar and "1-end s: house" in bar
    text, bar = studio.on_timeline([[0, "1", ""]], None)
    assert text.startswith("error: the timeline row 0-1 has no style") and bar == ""
