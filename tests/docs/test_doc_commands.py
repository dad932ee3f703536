"""Every command of the README, the getting-started page and the how-to guides runs as written.

The fenced ``bash`` blocks are read from the pages; each command is matched to a runner (RUNNERS, first match
wins) and a command without one fails the test, so a new command cannot go untested. Runners:

- ``run``: the command itself, in a working folder of its page (``DGSDP_HOME``), with tiny settings added
  (TINY: a 2-step tiny model, 2 sampling steps, a 4 s song, the hand-made dataset for ``/path/to/aistpp``);
  placeholders (PLACEHOLDERS) become a tiny checkpoint trained once for the whole module, a song, a dataset.
- ``config``: what needs what this machine cannot have (a GPU, SLURM, real AIST++ at paper size, Jukebox's
  weights): Hydra composes the command's config (``--cfg job``) and every ``key=value`` it sets is in it.
- ``help``: a tool whose input cannot be made here (EDGE's source, a finished sweep): its ``--help`` names every
  option the command uses.
- ``install``: the venv and pip steps of the quick start: the same as CI's (``.ci/run``), which runs them.
- ``studio``: the studio is started on a free port and serves its page.
- ``skip``: a download or an outside program (Blender), listed with the reason.

Files a page shows with a title (```` ```python title="my_plugins.py" ````) are written into the page's folder
first; its untitled ``python`` blocks run there as snippets (the README's is run by tests/api). All runs share one
interpreter (tests/cli/cli_driver.py), so the imports are paid once.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
DRIVER = REPO / "tests" / "cli" / "cli_driver.py"
PAGES = ["README.md", "docs/getting-started.md", *sorted(str(p.relative_to(REPO)) for p in (REPO / "docs" / "guides").glob("*.md"))]  # fmt: skip
SONG_SECONDS = 4.0

# command pattern -> (runner, why); the first match wins.
RUNNERS: list[tuple[str, str, str]] = [
    (r"^git clone ", "skip", "downloads EDGE's repository and its weights (network)"),
    (r"^blender ", "skip", "needs Blender; tests/export/test_blender_import.py imports the same files with bpy (slow)"),
    (r"^python3 -m venv |^\. \.venv/bin/activate$|^pip install ", "install", "the quick start's set-up, as .ci/run"),
    (r"^python -m pytest$", "install", "CI's own test command (.ci/run)"),
    (r"^mkdocs serve$", "docs", "the site's configuration loads; CI builds it with mkdocs build --strict"),
    (r"^python -m dgsdp\.interop\.edge verify ", "help", "needs EDGE's source checkout"),
    (r"^python -m dgsdp\.report ", "help", "needs a finished sweep of the paper-size rows"),
    (r"^python -m dgsdp\.sweep table4 --jobs ", "config", "trains 18 paper-size jobs: composed with --dry-run"),
    (r"hydra/launcher=submitit_slurm", "config", "needs SLURM and the slurm extra: composed without the launcher"),
    (
        r"(train\.py|dgsdp-train).*(experiment=table|model=paper|trainer=gpu|audio=jukebox)",
        "config",
        "needs a GPU, real AIST++ at paper size or Jukebox's weights",
    ),  # fmt: skip
    (
        r"train\.py trainer=ddp .*trainer\.accelerator=cpu$",
        "config",
        "starts 2 processes (minutes of start-up): tests/training/test_ddp.py runs it",
    ),  # fmt: skip
    (r"^dgsdp-studio ", "studio", "serves its page"),
    (r"^python (train|generate|evaluate)\.py", "run", ""),
    (r"^python -m dgsdp\.(quickstart|sweep|interop\.edge import|audio\.extract)\b", "run", ""),
]

# the placeholders the runs fill in (<ckpt>, the dataset: the fixture; <run>: the newest run of the page's folder;
# <time>: only in commands checked by --help)
PLACEHOLDERS = ("<ckpt>", "<run>", "<time>")
# tiny settings added to a run, by entry point, unless the command sets the key itself
TINY = {
    "train.py": ["debug=tiny", "trainer.max_steps=2", "trainer.max_epochs=-1", "trainer.limit_val_batches=0",
                 "logger=none", "data.progress=false", "callbacks.progress.refresh_rate=0", "data.num_workers=0",
                 "data.root=@DATA", "data.synthetic=null", "paths.cache_dir=@CACHE"],
    "generate.py": ["device=cpu", "progress=false", "sampling.steps=2", "formats=[npy]", "paths.cache_dir=@CACHE"],
    "evaluate.py": ["device=cpu", "progress=false", "sampling.steps=2", "protocol.trials=1",
                    "protocol.guidance_weights=[2.0]", "logger=none", "paths.cache_dir=@CACHE"],
    "dgsdp.quickstart": ["debug=tiny", "trainer.max_steps=2", "logger=none", "data.root=@DATA",
                         "data.synthetic=null", "paths.cache_dir=@CACHE"],
}  # fmt: skip
PYPROJECT = (REPO / "pyproject.toml").read_text()
# [project.scripts]: console script -> "module:function" (read as text: tomllib is Python 3.11+)
CONSOLE_SCRIPTS = dict(
    re.findall(r'^(dgsdp-[\w-]+) = "([\w.:]+)"$', PYPROJECT.split("[project.scripts]")[1], flags=re.M)
)
SCRIPTS = {"train.py": "train.py", "generate.py": "generate.py", "evaluate.py": "evaluate.py",
           "dgsdp-train": "train.py", "dgsdp-generate": "generate.py", "dgsdp-evaluate": "evaluate.py"}  # fmt: skip


@dataclass
class Command:
    page: str
    text: str  # as written
    runner: str
    why: str
    files: dict[str, str] = field(default_factory=dict)  # the page's titled blocks: name -> text

    @property
    def name(self) -> str:
        return f"{self.page}: {self.text}"


def fenced_blocks(text: str) -> list[tuple[str, str, str]]:
    """(language, title, body) of every fenced block."""
    pattern = r'^```(\w+)(?:[ \t]+title="([^"]+)")?[ \t]*\n(.*?)^```[ \t]*$'
    return [(m[1], m[2] or "", m[3]) for m in re.finditer(pattern, text, flags=re.S | re.M)]


def commands_of(block: str) -> list[str]:
    """One command per line (a trailing backslash continues it), comments and blank lines left out."""
    joined = re.sub(r"\\\n\s*", " ", block)
    out = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        if words:
            out.append(" ".join(shlex.quote(w) if w != "&&" else w for w in words))
    return out


def plan(page: str) -> list[Command]:
    text = (REPO / page).read_text()
    blocks = fenced_blocks(text)
    files = {title: body for lang, title, body in blocks if title}
    planned = []
    for lang, _title, body in blocks:
        if lang != "bash":
            continue
        for line in commands_of(body):
            for segment in line.split(" && ") if " && " in line and not line.startswith("git clone") else [line]:
                bare = re.sub(r"^(?:[A-Z_]+=\S+ )+", "", segment)  # the command without its variables
                runner = next(((r, why) for pat, r, why in RUNNERS if re.search(pat, bare)), ("", ""))
                planned.append(Command(page, segment, runner[0], runner[1], files))
    return planned


ALL = [c for page in PAGES for c in plan(page)]


def test_every_command_has_a_runner():
    missing = [c.name for c in ALL if not c.runner]
    assert not missing, "commands with no runner in tests/docs/test_doc_commands.py (add one to RUNNERS):\n" + "\n".join(missing)  # fmt: skip
    assert {c.page for c in ALL} == set(PAGES)  # every page has commands
    assert sum(c.runner == "run" for c in ALL) >= 20
    unknown = [c.name for c in ALL if c.runner != "skip" and set(re.findall(r"<[^>]+>", c.text)) - set(PLACEHOLDERS)]
    assert not unknown, f"placeholders no runner fills in: {unknown}"


def test_install_commands_are_ci_s():
    """The quick start's set-up steps are the ones .ci/run runs in a fresh clone (pip's -q aside), so CI installs
    exactly as the README says."""
    ci = {
        tuple(w for w in shlex.split(segment, comments=True) if w != "-q")
        for line in (REPO / ".ci" / "run").read_text().splitlines()
        for segment in line.split(" && ")
    }
    for c in (c for c in ALL if c.runner == "install"):
        words = tuple(w for w in shlex.split(c.text) if w != "-q")
        if words == ("pip", "install", "-e", ".[slurm]"):
            assert re.search(r"^slurm = \[", PYPROJECT, flags=re.M)
            continue
        assert words in ci, c.name


def _words(c: Command, values: dict[str, str]) -> tuple[dict[str, str], list[str]]:
    """(environment prefix, words) of a command with its placeholders filled."""
    text = c.text
    for key in ("<ckpt>", "/path/to/aistpp"):
        text = text.replace(key, values[key])
    words = shlex.split(text)
    env = {}
    while words and re.match(r"^[A-Z_]+=", words[0]):
        k, _, v = words.pop(0).partition("=")
        env[k] = v
    return env, words


def _target(words: list[str]) -> tuple[dict, list[str], str]:
    """The driver's target of a command, its argv, and the key of its tiny settings."""
    if words[0] == "python" and words[1] == "-m":
        module = words[2]
        key = "dgsdp.interop.edge" if module.startswith("dgsdp.interop.edge") else module
        return {"module": module}, words[3:], key
    if words[0] == "python":
        return {"script": str(REPO / SCRIPTS[words[1]])}, words[2:], words[1]
    if words[0] in SCRIPTS:
        return {"script": str(REPO / SCRIPTS[words[0]])}, words[1:], SCRIPTS[words[0]]
    return {"entry": CONSOLE_SCRIPTS[words[0]]}, words[1:], words[0]


def _keys(argv: list[str]) -> set[str]:
    return {a.split("=", 1)[0].lstrip("+~") for a in argv if "=" in a and not a.startswith("-")}


def job_for(c: Command, values: dict[str, str], folder: Path) -> dict:
    """The driver's job for a run, config or help command."""
    env, words = _words(c, values)
    target, argv, key = _target(words)
    job = {"name": c.text, **target, "cwd": str(folder), "env": {"DGSDP_HOME": str(folder), **env}}
    if env.get("PYTHONPATH") == ".":
        job["path"] = [str(folder)]
    if c.runner == "help":
        return {**job, "argv": ["--help"] if key != "dgsdp.interop.edge" else [argv[0], "--help"]}
    if c.runner == "config":
        if key == "dgsdp.sweep":
            return {**job, "argv": [a for a in argv if a not in ("--jobs", "2")] + ["--dry-run"]}
        argv = [a for a in argv if a != "-m" and not a.startswith(("hydra/launcher=", "hydra.launcher."))]
        return {**job, "argv": [*argv, "--cfg", "job"]}
    tiny = [t.replace("@DATA", values["data"]).replace("@CACHE", values["cache"]) for t in TINY.get(key, [])]
    if key == "train.py" and "ckpt_path" in _keys(argv):
        tiny = [t if not t.startswith("trainer.max_steps=") else "trainer.max_steps=4" for t in tiny]
    if key == "generate.py" and "task" in _keys(argv):  # an edit: the given motion has the song's length
        tiny = [*tiny, f"seconds={SONG_SECONDS}"]
    argv = [*argv, *(t for t in tiny if t.split("=", 1)[0] not in _keys(argv))]
    return {**job, "argv": argv, "globs": {"<run>": "outputs/train/runs/*"}}


def write_page_files(c: Command, folder: Path) -> None:
    for name, body in c.files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(body)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_studio(c: Command, values: dict[str, str], folder: Path) -> tuple[subprocess.Popen, int]:
    env, words = _words(c, values)
    port = free_port()
    argv = [sys.executable, "-c", "from dgsdp.studio import main; main()", *words[1:], "--port", str(port),
            "--work-dir", str(folder / "studio"), "--outputs", str(folder / "outputs"), "--device", "cpu"]  # fmt: skip
    env = {**os.environ, **env, "PYTHONPATH": str(REPO), "DGSDP_HOME": str(folder), "OMP_NUM_THREADS": "1"}
    log = open(folder / f"studio-{port}.log", "w")  # noqa: SIM115 - closed with the process
    return subprocess.Popen(argv, cwd=folder, env=env, stdout=log, stderr=subprocess.STDOUT), port


def page_served(port: int, proc: subprocess.Popen, timeout: float = 180.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as r:
                return r.read().decode("utf-8", "replace")
        except OSError:
            time.sleep(0.5)
    return ""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every page's commands, run once: a tiny checkpoint (free-text styles), a song, a dataset and an EDGE-format
    checkpoint in each page's folder; then all run/config/help jobs in one interpreter, and the studios."""
    from generation.gen_helpers import train_tiny_checkpoint, write_click_song
    from interop.edge_format import write_edge_checkpoint
    from motion_helpers import random_motion

    tmp = tmp_path_factory.mktemp("doc_commands")
    checkpoint = train_tiny_checkpoint(tmp / "train", style="prompt")
    values = {"<ckpt>": str(checkpoint), "/path/to/aistpp": str(tmp / "train" / "data"),
              "data": str(tmp / "train" / "data"), "cache": str(tmp / "cache")}  # fmt: skip
    folders, jobs, studios = {}, [], {}
    for page in PAGES:
        folder = tmp / re.sub(r"\W+", "_", page)
        folder.mkdir()
        folders[page] = folder
        for song in ("song.wav", "my_song.wav"):
            write_click_song(folder / song, SONG_SECONDS)
        np.save(folder / "dance.npy", random_motion(int(SONG_SECONDS * 30), seed=1).numpy())
        (folder / "EDGE").mkdir()
        write_edge_checkpoint(folder / "EDGE" / "checkpoint.pt", 35, d=32, layers=2, ff=64)
        shutil.copy(folder / "EDGE" / "checkpoint.pt", folder / "checkpoint.pt")
        shutil.copy(checkpoint, folder / "model.ckpt")
    for c in ALL:
        folder = folders[c.page]
        write_page_files(c, folder)
        if c.runner in ("run", "config", "help") and c.text not in {j["name"] for j in jobs}:
            jobs.append(job_for(c, values, folder))  # a command on two pages runs once (results are by command)
    for page in PAGES:  # the pages' untitled Python blocks, after their commands (they use what those wrote)
        text = (REPO / page).read_text()
        for k, (lang, title, body) in enumerate(fenced_blocks(text)):
            if lang == "python" and not title and page != "README.md" and "blender_import" not in body:
                snippet = folders[page] / f"snippet_{k}.py"
                snippet.write_text(body)
                jobs.append({"name": f"{page}: python block {k}", "exec": str(snippet), "argv": [],
                             "cwd": str(folders[page]), "env": {"DGSDP_HOME": str(folders[page])},
                             "path": [str(folders[page])]})  # fmt: skip
    # the studios start while the jobs run (their edge.ckpt comes from a job: they wait for it)
    (tmp / "jobs.json").write_text(json.dumps(jobs))
    env = {
        **os.environ,
        "PYTHONPATH": str(REPO),
        "HF_HUB_OFFLINE": "1",
        "WANDB_MODE": "offline",
        "OMP_NUM_THREADS": "1",
    }
    proc = subprocess.run(
        [sys.executable, str(DRIVER), str(tmp / "results.json"), str(tmp / "jobs.json")],
        cwd=tmp, env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads((tmp / "results.json").read_text())
    print("seconds per command:", json.dumps({k: round(v["seconds"], 1) for k, v in results.items()}, indent=1))
    for c in (c for c in ALL if c.runner == "studio"):
        if c.text not in studios:  # a command on two pages runs once (results are by command)
            studios[c.text] = start_studio(c, values, folders[c.page])
    pages = {name: page_served(port, p) for name, (p, port) in studios.items()}
    for p, _ in studios.values():
        p.terminate()
        p.wait(timeout=30)
    return {"results": results, "studios": pages, "folders": folders, "values": values}


def _ok(result: dict) -> bool:
    return result["code"] == 0


@pytest.mark.parametrize("c", [c for c in ALL if c.runner == "run"], ids=lambda c: c.name)
def test_run(runs, c):
    result = runs["results"][c.text]
    assert _ok(result), (result["code"], result["stdout"][-2000:], result["stderr"][-3000:])


@pytest.mark.parametrize("c", [c for c in ALL if c.runner == "config"], ids=lambda c: c.name)
def test_config(runs, c):
    """Composed as written (the parts this machine lacks aside); each key=value it sets is in the config."""
    result = runs["results"][c.text]
    assert _ok(result), (result["code"], result["stderr"][-3000:])
    if "--jobs" in c.text:
        assert "job" in result["stdout"].lower()
        return
    cfg = yaml.safe_load(result["stdout"])
    _, words = _words(c, runs["values"])
    for word in words:
        key, eq, value = word.partition("=")
        if not eq or "." not in key or key.startswith(("hydra", "-")):
            continue
        node = cfg
        for part in key.split("."):
            node = node[part]
        assert _same(node, value), (key, node, value)


def _same(composed, written: str) -> bool:
    """A composed value equals the command line's (numbers by value: Hydra reads 2e-4 as 0.0002)."""
    try:
        return float(composed) == float(written)
    except (TypeError, ValueError):
        return str(composed) == str(yaml.safe_load(written))


@pytest.mark.parametrize("c", [c for c in ALL if c.runner == "help"], ids=lambda c: c.name)
def test_help_names_every_option(runs, c):
    result = runs["results"][c.text]
    assert _ok(result), result
    for option in re.findall(r"(?<!\S)(--[a-z][\w-]*)", c.text):
        assert option in result["stdout"], (option, result["stdout"][:2000])


@pytest.mark.parametrize("c", [c for c in ALL if c.runner == "studio"], ids=lambda c: c.name)
def test_studio_serves_its_page(runs, c):
    assert "<html" in runs["studios"][c.text].lower()


def test_docs_serve_loads_the_site_config():
    from mkdocs.config import load_config

    config = load_config(str(REPO / "mkdocs.yml"))
    assert config["site_name"] == "dgsdp" and config["theme"].name == "material"
    assert (REPO / config["docs_dir"] / "index.md").is_file()


def test_the_pages_python_blocks_run(runs):
    snippets = {k: v for k, v in runs["results"].items() if "python block" in k}
    assert len(snippets) >= 2
    for name, result in snippets.items():
        assert _ok(result), (name, result["code"], result["stderr"][-3000:])


def test_the_runs_wrote_what_the_pages_say(runs):
    folders = runs["folders"]
    edit = folders["docs/guides/edit-a-dance.md"]
    assert np.load(edit / "first" / "song.npy").shape == (int(SONG_SECONDS * 30), 151)
    blender = folders["docs/guides/blender.md"]
    assert {p.name for p in (blender / "blender").iterdir()} >= {"song.bvh", "song.glb"}
    assert (folders["docs/guides/edge-weights.md"] / "edge.ckpt").is_file()
    assert (folders["docs/guides/plugins.md"] / "plugin_run" / "checkpoints" / "last.ckpt").is_file()
    assert (folders["docs/guides/plugins.md"] / "plugin_dance.bvh").is_file()
    quickstart = runs["results"]["python -m dgsdp.quickstart"]  # what the getting-started page shows it print
    checkpoint = re.search(r"^checkpoint: (\S+/outputs/quickstart/[^/]+/train/checkpoints/last\.ckpt)$",
                           quickstart["stdout"], flags=re.M)  # fmt: skip
    assert checkpoint and Path(checkpoint[1]).is_file(), quickstart["stdout"][-2000:]
    assert f"next: dgsdp-generate checkpoint={checkpoint[1]} music=<your song>" in quickstart["stdout"]
    dances = Path(checkpoint[1]).parents[2] / "dances"
    for kind in ("genre", "free_text"):
        suffixes = {p.suffix for p in (dances / kind).iterdir()}
        assert {".pkl", ".bvh", ".npy"} <= suffixes and suffixes & {".mp4", ".gif"}, (kind, suffixes)
    listed = {c.runner for c in ALL}
    assert listed <= {"run", "config", "help", "install", "docs", "studio", "skip"}
