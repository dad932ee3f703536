"""Fixtures of the studio tests: a tiny trained checkpoint, songs, and the studio served on a free local port."""

import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from generation.gen_helpers import train_tiny_checkpoint, write_click_song

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def studio_checkpoint(tmp_path_factory) -> str:
    """A tiny model trained for two steps (one-hot style, librosa features)."""
    return train_tiny_checkpoint(tmp_path_factory.mktemp("studio_tiny"))


@pytest.fixture(scope="session")
def studio_songs(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("studio_songs")
    paths = {"three": d / "three.wav", "two": d / "two.wav", "broken": d / "broken.wav", "long": d / "long.wav"}
    write_click_song(paths["three"], 3.0)
    write_click_song(paths["two"], 2.0, bpm=100)
    paths["broken"].write_bytes(b"RIFF this is not audio at all" * 50)
    sf.write(paths["long"], np.zeros(30 * 1000, dtype=np.int16), 1000, subtype="PCM_16")  # 30 s of silence
    return paths


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def chromium() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        pytest.skip("chromium is not installed (apt-get install chromium); the browser tests need it")
    return path


@pytest.fixture(scope="session")
def browser_type_launch_args(chromium) -> dict:
    """pytest-playwright launches the system chromium (nothing is downloaded)."""
    return {"executable_path": chromium, "args": ["--no-sandbox", "--autoplay-policy=no-user-gesture-required"]}


@pytest.fixture(scope="session")
def browser_context_args() -> dict:
    return {"viewport": {"width": 1280, "height": 1000}, "accept_downloads": True}


@pytest.fixture(scope="session")
def studio_url(chromium, studio_checkpoint, tmp_path_factory):
    """``python -m dgsdp.studio`` serving the tiny checkpoint on a free 127.0.0.1 port (2 DDIM steps by default)."""
    work = tmp_path_factory.mktemp("studio_work")
    port = free_port()
    log_path = work / "server.log"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    command = [
        sys.executable, "-m", "dgsdp.studio", "--checkpoint", studio_checkpoint, "--port", str(port),
        "--work-dir", str(work / "studio"), "--outputs", str(work / "outputs"), "--steps", "2",
        "--max-seconds", "20", "--max-upload-mb", "2", "--device", "cpu",
    ]  # fmt: skip
    with open(log_path, "w") as log:
        proc = subprocess.Popen(command, cwd=work, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}/"
    deadline = time.monotonic() + 180
    try:
        while True:
            if proc.poll() is not None:
                pytest.fail(f"the studio exited with code {proc.returncode}:\n{log_path.read_text()}")
            try:
                with urllib.request.urlopen(url, timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                pytest.fail(f"the studio did not answer at {url} within 180 s:\n{log_path.read_text()}")
            time.sleep(0.5)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="session")
def serve_studio():
    """``serve_studio(config)``: a context manager serving that studio from this process (see serve_in_process)."""
    return serve_in_process


@contextmanager
def serve_in_process(config):
    """The studio of ``config`` served from this process on a free 127.0.0.1 port: yields (url, Studio)."""
    from dgsdp.studio.app import build_app, launch_kwargs

    demo, studio = build_app(config)
    port = free_port()
    demo.launch(**{**launch_kwargs(config, studio), "server_port": port, "prevent_thread_lock": True, "quiet": True})
    try:
        yield f"http://127.0.0.1:{port}/", studio
    finally:
        demo.close()
