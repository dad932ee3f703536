"""The studio shared with a team, through the Gradio client: what one user can do to the server and to the others.

Each test serves the studio from this process (the ``serve_studio`` fixture) and talks to it as a remote client would:
long styles, crafted checkpoint paths, logins, each login's files kept to that login, slow requests holding the
queue, non-finite numbers, and the retention of run folders and uploads.
"""

import datetime
import json
import os
import re
import shutil
import time
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace
from urllib.parse import quote

import httpx
import numpy as np
import pytest
import torch

pytest.importorskip("gradio", reason="the studio needs Gradio: pip install -e '.[studio]'")

import gradio as gr  # noqa: E402
from audio.audio_synth import flac_without_length  # noqa: E402
from generation.gen_helpers import write_click_song  # noqa: E402
from gradio_client import Client, handle_file  # noqa: E402
from gradio_client.exceptions import AppError  # noqa: E402

from dgsdp.studio.app import (  # noqa: E402
    MAX_STYLE_CHARS,
    StudioConfig,
    parse_args,
    sharing_warning,
)

pytestmark = pytest.mark.timeout(300)

LISTED = "the models listed in the Model box"
HEADERS = ["start (s)", "end (s, or end)", "style"]


def timeline(*rows) -> dict:
    """The timeline's value as a client sends it."""
    return {"headers": HEADERS, "data": [list(row) for row in rows]}


def rss_bytes() -> int:
    """This process's resident memory (the server runs in it)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS in /proc/self/status")


def config(tmp: Path, checkpoint: str, **overrides) -> StudioConfig:
    """A studio listing one run (``tmp/outputs/run/checkpoints/last.ckpt``, a copy of ``checkpoint``)."""
    run = tmp / "outputs" / "run" / "checkpoints" / "last.ckpt"
    run.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(checkpoint, run)
    values = {"outputs": str(tmp / "outputs"), "work_dir": str(tmp / "studio"), "max_song_seconds": 20,
              "max_upload_mb": 2, "device": "cpu", "default_steps": 2, **overrides}  # fmt: skip
    return StudioConfig(**values)


@contextmanager
def uploads_in(folder: Path):
    """Gradio's upload folder set to ``folder`` meanwhile (dgsdp-studio sets it to its work folder's uploads)."""
    before = os.environ.get("GRADIO_TEMP_DIR")
    os.environ["GRADIO_TEMP_DIR"] = str(folder)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("GRADIO_TEMP_DIR", None)
        else:
            os.environ["GRADIO_TEMP_DIR"] = before


@pytest.fixture(scope="module")
def shared(studio_checkpoint, serve_studio, tmp_path_factory):
    """A studio as a team would run it: listed runs only, 2 runs kept, uploads in its work folder."""
    tmp = tmp_path_factory.mktemp("shared")
    with uploads_in(tmp / "studio" / "uploads"):
        with serve_studio(config(tmp, studio_checkpoint, keep_runs=2, request_timeout_s=120)) as served:
            yield served


@pytest.fixture(scope="module")
def songs(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("shared_songs")
    paths = {"three": d / "three.wav", "five": d / "five.wav", "twenty": d / "twenty.wav", "flac": d / "stream.flac"}
    write_click_song(paths["three"], 3.0)
    write_click_song(paths["five"], 5.0)
    write_click_song(paths["twenty"], 20.0)
    flac_without_length(paths["flac"], 3.0)
    return paths


def generate_values(studio, **overrides) -> dict:
    """Generate's settings after the song, in the page's order."""
    values = {"checkpoint": studio.checkpoints()[0], "genre": "Krump", "free_text": "", "rows": timeline(),
              "music_w": 1.0, "style_w": 1.0, "sampler": "ddim", "steps": 2, "seed": 0, "video": False,
              "cleanup": True}  # fmt: skip
    return {**values, **overrides}


def generate(client: Client, studio, song: Path, **overrides):
    values = generate_values(studio, **overrides)
    return client.predict(handle_file(str(song)), *values.values(), api_name="/on_generate")


def load_model(client: Client, checkpoint: str) -> str:
    return client.predict(checkpoint, "Krump", api_name="/on_checkpoint")[1]


def test_a_long_style_with_video_is_rendered_quickly_and_longer_ones_are_refused(shared, songs):
    url, studio = shared
    client = Client(url, verbose=False)
    # the tiny model knows genres only: a 1,000-character style is a timeline of 40 spans of genres
    names = ["LA-style Hip-hop", "Middle Hip-hop", "Ballet Jazz", "Street Jazz"]
    rows = timeline(*[[i / 8, f"{(i + 1) / 8:g}", names[i % 4]] for i in range(40)])
    viewer, files, status = generate(client, studio, songs["five"], rows=rows, video=True)  # warm-up: features
    started = time.monotonic()
    viewer, files, status = generate(client, studio, songs["five"], rows=rows, video=True, seed=1)
    elapsed = time.monotonic() - started
    assert len(json.loads(viewer)["label"]) > 1000  # the video's title: the song and the style
    assert "150 frames (5.0 s)" in status
    assert any(Path(f).suffix in (".mp4", ".gif") for f in files), files  # the video was rendered
    assert elapsed < 30, f"a 5 s song with a 1,000-character style took {elapsed:.1f} s"
    style = "k" * MAX_STYLE_CHARS
    with pytest.raises(AppError, match="the style has 1001 characters; the limit is 1000"):
        generate(client, studio, songs["three"], free_text=style + "x")
    with pytest.raises(AppError, match="the timeline row 0-end's style has 1001 characters"):
        generate(client, studio, songs["three"], rows=timeline([0, "end", style + "x"]))
    with pytest.raises(AppError, match="the timeline has 51 rows; give at most 50 spans"):
        generate(client, studio, songs["three"], rows=timeline(*[[i, i + 1, "Krump"] for i in range(51)]))


def crafted_checkpoint(checkpoint: str, path: Path) -> Path:
    """The tiny checkpoint's weights under a config that asks for a model of terabytes (d_model 2**18)."""
    ckpt = torch.load(checkpoint, map_location="cpu", weights_only=True)
    ckpt["hyper_parameters"]["model"].update(d_model=2**18, n_layers=64, ff_dim=2**20)
    torch.save(ckpt, path)
    assert path.stat().st_size < 2 * 2**20
    return path


def upload(url: str, path: Path) -> str:
    """Upload a file as any client can; returns the path the server stored it at."""
    with open(path, "rb") as f:
        response = httpx.post(f"{url}gradio_api/upload", files=[("files", (path.name, f.read()))], timeout=30)
    response.raise_for_status()
    return response.json()[0]


def test_the_model_box_opens_only_the_runs_it_lists(shared, songs, studio_checkpoint, tmp_path):
    url, studio = shared
    client = Client(url, verbose=False)
    assert load_model(client, studio.checkpoints()[0]).startswith("Loaded")
    crafted = upload(url, crafted_checkpoint(studio_checkpoint, tmp_path / "crafted.ckpt"))
    assert Path(crafted).is_file()  # the upload API tells the client where the file is
    # the same message for the uploaded file, a missing file, a folder and a device: nothing to probe
    for typed in (crafted, "/nowhere/model.ckpt", str(tmp_path), "/dev/zero", studio_checkpoint):
        with pytest.raises(AppError) as error:
            load_model(client, typed)
        assert str(error.value).startswith(f"choose one of {LISTED}; this studio does not open other paths")
        with pytest.raises(AppError, match=LISTED):
            generate(client, studio, songs["three"], checkpoint=typed)  # Generate checks the box too
    assert rss_bytes() < 2 * 2**30


@pytest.fixture(scope="module")
def open_paths(studio_checkpoint, serve_studio, tmp_path_factory):
    """A studio started with --allow-checkpoint-paths."""
    tmp = tmp_path_factory.mktemp("open_paths")
    with serve_studio(config(tmp, studio_checkpoint, allow_checkpoint_paths=True)) as served:
        yield served


def test_typed_paths_with_the_flag_get_one_clean_message(open_paths, studio_checkpoint, tmp_path):
    url, _ = open_paths
    client = Client(url, verbose=False)
    assert load_model(client, studio_checkpoint).startswith("Loaded")
    for typed in (str(tmp_path), "/dev/zero"):
        with pytest.raises(AppError, match=f"{typed} is not a checkpoint file"):
            load_model(client, typed)
    pickled = tmp_path / "pickled.ckpt"
    torch.save({"hyper_parameters": {}, "state_dict": {}, "when": datetime.datetime(2020, 1, 1)}, pickled)
    with pytest.raises(AppError) as error:
        load_model(client, str(pickled))
    message = str(error.value)
    assert "the Python global datetime.datetime" in message and "nothing was loaded" in message
    assert "weights_only" not in message and "\x1b" not in message and message.count("\n") == 0
    assert message.endswith("or by the EDGE import.")  # whole, not cut


def test_a_crafted_checkpoint_path_is_refused_before_building_its_model(open_paths, studio_checkpoint, tmp_path):
    url, _ = open_paths
    client = Client(url, verbose=False)
    crafted = crafted_checkpoint(studio_checkpoint, tmp_path / "crafted.ckpt")
    with pytest.raises(AppError) as error:
        load_model(client, str(crafted))
    assert str(crafted) in str(error.value)  # a clear message about this checkpoint, not an allocation error
    assert rss_bytes() < 2 * 2**30


def test_a_wrong_password_is_refused(studio_checkpoint, serve_studio, tmp_path):
    logins = tmp_path / "logins.txt"
    logins.write_text("# the team\nalice:secret\n\nbob:pa:ss\n")
    parsed = parse_args(["--auth", "carol:c", "--auth-file", str(logins)])
    assert parsed.auth == [("carol", "c"), ("alice", "secret"), ("bob", "pa:ss")]
    with serve_studio(config(tmp_path, studio_checkpoint, auth=parsed.auth)) as (url, _):
        with pytest.raises(ValueError, match="Could not login"):
            Client(url, auth=("alice", "wrong"), verbose=False)
        assert httpx.get(f"{url}config", timeout=10).status_code == 401  # nothing without a login
        client = Client(url, auth=("alice", "secret"), verbose=False)
        assert client.predict(timeline([0, "1", "krump"]), None, api_name="/on_timeline")[0] == '0-1: "krump"'


def test_serving_beyond_this_machine_warns(capsys):
    assert sharing_warning(parse_args([])) is None
    assert sharing_warning(parse_args(["--host", "127.0.0.2"])) is None
    open_to_all = sharing_warning(parse_args(["--host", "0.0.0.0"]))
    assert "serves the studio to the network" in open_to_all and "with no login" in open_to_all
    assert "--auth USER:PASSWORD" in open_to_all
    with_login = sharing_warning(parse_args(["--host", "0.0.0.0", "--auth", "alice:secret"]))
    assert "login page" in with_login and "no login" not in with_login and "any .ckpt" not in with_login
    typed = sharing_warning(parse_args(["--host", "0.0.0.0", "--auth", "a:b", "--allow-checkpoint-paths"]))
    assert "users can open any .ckpt on this machine" in typed
    for bad in (["--auth", "alice"], ["--auth", ":x"], ["--request-timeout", "0"], ["--keep-runs", "-1"]):
        with pytest.raises(SystemExit):
            parse_args(bad)
    assert "USER:PASSWORD" in capsys.readouterr().err


def test_a_slow_request_does_not_hold_the_queue_past_the_time_limit(studio_checkpoint, serve_studio, songs, tmp_path):
    with serve_studio(config(tmp_path, studio_checkpoint, request_timeout_s=3)) as (url, studio):
        slow_client, quick_client = Client(url, verbose=False), Client(url, verbose=False)
        ckpt = studio.checkpoints()[0]
        load_model(quick_client, ckpt)  # the model is in memory: the quick request's time is its own
        args = ["Krump", "", timeline(), 1.0, 1.0, "ddim"]
        slow = slow_client.submit(handle_file(str(songs["twenty"])), ckpt, *args, 1000, 0, True, True,
                                  api_name="/on_generate")  # fmt: skip
        time.sleep(0.5)  # the slow request is running
        started = time.monotonic()
        quick = quick_client.submit(handle_file(str(songs["three"])), ckpt, *args, 2, 0, False, True,
                                    api_name="/on_generate")  # fmt: skip
        status = quick.result(timeout=120)[2]
        waited = time.monotonic() - started
        assert "90 frames (3.0 s)" in status
        assert waited < 3 + 20, f"the second user waited {waited:.1f} s behind a request limited to 3 s"
        with pytest.raises(AppError, match=r"stopped at the studio's time limit of 3 s per request \(--request"):
            slow.result(timeout=60)
        runs = list((studio.work_dir / "runs").iterdir())
        assert len(runs) == 1 and (runs[0] / "viewer.json").is_file()  # the stopped request left nothing


def test_non_finite_numbers_get_one_clear_message(shared, songs):
    url, studio = shared
    client = Client(url, verbose=False)
    nan_row = timeline(["nan", "3", "Break"])
    assert client.predict(nan_row, None, api_name="/on_timeline")[0].startswith(
        "error: the timeline row nan-3: times are seconds (finite numbers)"
    )
    for rows, message in (
        (nan_row, "the timeline row nan-3: times are seconds \\(finite numbers\\)"),
        (timeline([0, "inf", "Break"]), "the timeline row 0-inf: times are seconds \\(finite numbers\\)"),
        (timeline(["-inf", "end", "Break"]), "the timeline row -inf-end: times are seconds \\(finite numbers\\)"),
    ):
        with pytest.raises(AppError, match=message):
            generate(client, studio, songs["three"], rows=rows)
    with pytest.raises(AppError, match="Seed must be a whole number, got 1.5"):
        generate(client, studio, songs["three"], seed=1.5)
    generate(client, studio, songs["three"])  # a current dance to edit
    edit_args = ["Break", "", timeline(), 1.0, 1.0, "ddim", 2, 0, False]
    keyframes = "Keep poses at keyframes (seconds), regenerate the rest"
    for keyframe_text in ("nan", "1, inf"):
        with pytest.raises(AppError, match=f"'{keyframe_text.split()[-1]}' is not a time in seconds"):
            client.predict(handle_file(str(songs["three"])), studio.checkpoints()[0], *edit_args, keyframes,
                           keyframe_text, 1.0, 2.0, 4.0, True, api_name="/on_edit")  # fmt: skip

    # NaN in a number field or slider (JSON clients may send it; the page cannot): the handler names the field
    def no_progress(*args, **kwargs) -> None:
        return None

    song = str(songs["three"])
    for field, what in (("music_w", "Music guidance"), ("steps", "Steps"), ("seed", "Seed")):
        values = generate_values(studio, rows=[], **{field: float("nan")})
        with pytest.raises(gr.Error, match=f"{what} must be a finite number, got nan"):
            studio.on_generate(song, *values.values(), progress=no_progress)
    values = list(generate_values(studio, rows=[]).values())
    current = studio.on_generate(song, *values, progress=no_progress)[2]
    with pytest.raises(gr.Error, match="Range start must be a finite number, got nan"):
        studio.on_edit(current, song, *values[:10], keyframes, "1", 1.0, float("nan"), 4.0, progress=no_progress)


def test_a_flac_without_a_length_in_its_header(shared, songs):
    url, studio = shared
    status = generate(Client(url, verbose=False), studio, songs["flac"])[2]
    assert "90 frames (3.0 s)" in status


def test_run_folders_and_uploads_are_kept_to_the_newest(shared, songs):
    url, studio = shared
    client = Client(url, verbose=False)
    runs, uploads = studio.work_dir / "runs", studio.uploads_dir()
    assert uploads is not None and uploads.is_relative_to(studio.work_dir)
    runs.mkdir(exist_ok=True)
    killed = runs / "20200101-000000-deadbeef"  # a request killed mid-way: no viewer.json
    killed.mkdir()
    (killed / "three.wav").write_bytes(b"x")
    os.utime(killed, (time.time() - 3600, time.time() - 3600))
    generate(client, studio, songs["three"])
    older_uploads = set(uploads.iterdir())
    assert older_uploads
    for song in ("five", "flac"):  # other songs (an upload's folder is named by its content)
        generate(client, studio, songs[song])
    left = sorted(runs.iterdir())
    assert len(left) == 2 and all((d / "viewer.json").is_file() for d in left)  # --keep-runs 2
    assert not killed.exists()
    assert not older_uploads & set(uploads.iterdir())  # two newer requests pushed the older uploads out
    newest = max(left, key=lambda d: (d / "viewer.json").stat().st_mtime_ns)  # names tie within a second
    assert np.load(next(newest.glob("*.npy"))).shape == (90, 151)  # the newest dance is whole


TEAM = [("alice", "alice-secret"), ("bob", "bob-secret")]


@pytest.fixture
def team(studio_checkpoint, serve_studio, tmp_path):
    """A studio with two logins, uploads in its work folder (one per test: Gradio reads its upload folder from the
    environment, which the module's ``shared`` studio needs back afterwards)."""
    with (
        uploads_in(tmp_path / "studio" / "uploads"),
        serve_studio(config(tmp_path, studio_checkpoint, auth=TEAM)) as served,
    ):
        yield served


def log_in(url: str, login: str) -> tuple[Client, httpx.Client]:
    """A login's Gradio client, and plain HTTP with the same login (its cookies) for the file routes."""
    client = Client(url, auth=(login, dict(TEAM)[login]), verbose=False)
    return client, httpx.Client(base_url=url, cookies=client.cookies, timeout=30)


def upload_as(http: httpx.Client, path: Path) -> Path:
    """Upload a file as the page does; returns the path the server stored it at."""
    response = http.post("gradio_api/upload", files=[("files", (path.name, path.read_bytes()))])
    response.raise_for_status()
    return Path(response.json()[0])


def refused(response: httpx.Response, target: str) -> bool:
    """Whether the answer is Gradio's refusal of a file it does not serve (the same for a missing file)."""
    return response.status_code == 403 and response.json() == {"detail": f"File not allowed: {target}."}


def file_data(path: Path) -> dict:
    """A file input as a client sends it once the file is on the server."""
    return {"path": str(path), "meta": {"_type": "gradio.FileData"}}


def call(http: httpx.Client, api_name: str, *data) -> tuple[str, object]:
    """One call of the page's API over plain HTTP (which sends a server path as is): (last event, its data)."""
    response = http.post(f"gradio_api/call/{api_name}", json={"data": list(data)})
    response.raise_for_status()
    stream = http.get(f"gradio_api/call/{api_name}/{response.json()['event_id']}", timeout=120).text
    event, payload = re.findall(r"event: (\w+)\ndata: (.*)", stream)[-1]
    return event, json.loads(payload)


def dance_folder(viewer: str) -> Path:
    """The run folder of a dance, from the viewer's link to its joints."""
    return Path(json.loads(viewer)["motion_url"].split("file=", 1)[1]).parent


def test_each_login_reads_only_its_own_dances_and_uploads(team, songs):
    url, studio = team
    alice, alice_http = log_in(url, "alice")
    bob, bob_http = log_in(url, "bob")
    viewer, files, _ = generate(alice, studio, songs["three"])
    # the client fetched the dance's downloads with alice's login, as her page does
    assert {".npy", ".bvh", ".pkl"} <= {Path(f).suffix for f in files}
    assert np.load(next(f for f in files if f.endswith(".npy"))).shape == (90, 151)
    run = dance_folder(viewer)
    bobs_run = dance_folder(generate(bob, studio, songs["five"])[0])
    upload = upload_as(alice_http, songs["twenty"])
    assert upload.is_relative_to(studio.uploads_dir())
    dance = sorted(p for p in run.iterdir() if p.is_file())  # the song's copy, the viewer's joints, the files
    assert {".wav", ".json", ".npy"} <= {p.suffix for p in dance}
    for path in [*dance, upload]:
        assert alice_http.get(f"gradio_api/file={path}").content == path.read_bytes()
        assert refused(bob_http.get(f"gradio_api/file={path}"), str(path))
    for path in bobs_run.iterdir():
        assert refused(alice_http.get(f"gradio_api/file={path}"), str(path))
    # each login's dances are in its own folder
    assert run.parent.name.startswith("login-alice-") and run.parent.parent == studio.work_dir / "runs"
    assert bobs_run.parent.name.startswith("login-bob-")

    npy = next(p for p in dance if p.suffix == ".npy")
    link = bobs_run / "link.npy"  # a link in bob's folder to alice's file
    link.symlink_to(npy)
    tricks = [
        str(npy),
        str(bobs_run / ".." / ".." / run.parent.name / run.name / npy.name),  # .. out of bob's folder
        os.path.relpath(npy),  # relative to the server's folder
        str(link),
        str(run / "missing.npy"),  # the same answer whether or not the file exists
        str(npy.parent / "no-such-folder" / ".." / npy.name),  # .. after a folder that does not exist
    ]
    for target in tricks:
        assert refused(bob_http.get("gradio_api/file=" + quote(target, safe="")), target)  # no / left to normalise
        assert refused(bob_http.get(f"gradio_api/file/{quote(target, safe='')}"), target)  # the older route
        assert bob_http.head("gradio_api/file=" + quote(target, safe="")).status_code == 403
        assert refused(
            bob_http.get("gradio_api/file=" + quote(target, safe=""), headers={"Range": "bytes=0-9"}), target
        )
    assert alice_http.get(
        "gradio_api/file=" + quote(str(npy), safe=""), headers={"Range": "bytes=0-9"}
    ).status_code in (200, 206)
    # the studio's other files (the feature cache) are nobody's, and a request without a login gets nothing
    cached = [p for p in (studio.work_dir / "cache").rglob("*") if p.is_file()]
    assert cached
    assert refused(alice_http.get(f"gradio_api/file={cached[0]}"), str(cached[0]))
    assert httpx.get(f"{url}gradio_api/file={npy}", timeout=10).status_code in (401, 403)
    # the example songs are every login's
    example = Path(studio.example_song("Krump"))
    for http in (alice_http, bob_http):
        assert http.get(f"gradio_api/file={example}").content == example.read_bytes()


def test_a_login_cannot_dance_to_or_edit_another_logins_files(team, songs):
    url, studio = team
    _, alice_http = log_in(url, "alice")
    _, bob_http = log_in(url, "bob")
    upload = upload_as(alice_http, songs["three"])
    values = list(generate_values(studio).values())
    gone = "the song three.wav is no longer on the server; upload it again"
    for target in (upload, upload.parent / "missing" / "three.wav"):  # the same message for a missing song
        event, message = call(bob_http, "on_generate", file_data(target), *values)
        assert event == "error" and message["error"] == gone
    assert call(alice_http, "on_generate", file_data(upload), *values)[1][3].startswith("90 frames (3.0 s)")
    # the timeline bar reads the length of one's own song only
    rows = timeline([0, "1", "Krump"])
    assert "3.0 s" in call(alice_http, "on_timeline", rows, file_data(upload))[1][1]
    assert "song length unknown" in call(bob_http, "on_timeline", rows, file_data(upload))[1][1]

    # the current dance is a session's; a session of another login cannot edit it
    def no_progress(*args, **kwargs) -> None:
        return None

    alice, bob = SimpleNamespace(username="alice"), SimpleNamespace(username="bob")
    values = list(generate_values(studio, rows=[]).values())  # as the handlers get them
    current = studio.on_generate(str(upload), *values, progress=no_progress, request=alice)[2]
    keep_range = ["Regenerate a time range", "", 1.0, 1.0, 2.0, True]
    with pytest.raises(gr.Error, match="generate a dance first"):
        studio.on_edit(current, str(upload), *values[:10], *keep_range, progress=no_progress, request=bob)
    edited = studio.on_edit(current, str(upload), *values[:10], *keep_range, progress=no_progress, request=alice)
    assert Path(edited[2]["motion"]).parent.parent.name.startswith("login-alice-")


def test_runs_are_kept_to_the_newest_across_logins(studio_checkpoint, serve_studio, songs, tmp_path):
    with uploads_in(tmp_path / "studio" / "uploads"):
        with serve_studio(config(tmp_path, studio_checkpoint, auth=TEAM, keep_runs=2)) as (url, studio):
            alice, bob = Client(url, auth=TEAM[0], verbose=False), Client(url, auth=TEAM[1], verbose=False)
            first = dance_folder(generate(alice, studio, songs["three"])[0])
            others = [dance_folder(generate(client, studio, songs["three"])[0]) for client in (bob, alice)]
            assert not first.exists()  # --keep-runs 2 counts every login's dances together
            assert sorted(p.parent for p in (studio.work_dir / "runs").rglob("viewer.json")) == sorted(others)
            assert others[0].parent.name.startswith("login-bob-") and others[1].parent == first.parent


def test_without_logins_every_file_is_served_as_before(shared, songs):
    url, studio = shared
    viewer = generate(Client(url, verbose=False), studio, songs["three"])[0]
    run = dance_folder(viewer)
    assert run.parent == studio.work_dir / "runs"  # one user: no login folders
    uploaded = Path(upload(url, songs["five"]))
    for path in (run / "viewer.json", uploaded):
        assert httpx.get(f"{url}gradio_api/file={path}", timeout=10).content == path.read_bytes()
