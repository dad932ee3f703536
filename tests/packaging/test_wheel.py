"""The wheel is self-contained: it ships every config, sweep file and data file the code reads, and, installed into
a fresh environment outside the source tree, it trains and generates from an empty folder, writing only there (slow).
"""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

import dgsdp
from dgsdp.resources import CONFIG_DIR, RESOURCES_DIR, SWEEPS_DIR

SHIPPED = {"conf": CONFIG_DIR, "sweeps": SWEEPS_DIR, "resources": RESOURCES_DIR}
SCRIPTS = (
    "dgsdp-train",
    "dgsdp-generate",
    "dgsdp-evaluate",
    "dgsdp-sweep",
    "dgsdp-report",
    "dgsdp-synth",
    "dgsdp-studio",
    "dgsdp-import-edge",
)


def build_wheel(repo_root: Path, tmp: Path) -> Path:
    """``pip wheel . --no-deps`` of a copy of the sources (the checkout stays clean; nothing downloads)."""
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(repo_root / name, src / name)
    shutil.copytree(Path(dgsdp.__file__).parent, src / "dgsdp", ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp / "wheel"
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out), str(src)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    (wheel,) = out.glob("dgsdp-*.whl")
    return wheel


@pytest.fixture(scope="module")
def wheel(repo_root, tmp_path_factory) -> Path:
    return build_wheel(repo_root, tmp_path_factory.mktemp("build"))


def test_wheel_ships_configs_sweeps_and_data_files(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder_name, folder in SHIPPED.items():
        files = [p for p in folder.rglob("*") if p.is_file() and "__pycache__" not in p.parts]
        expected = {f"dgsdp/{folder_name}/{p.relative_to(folder).as_posix()}" for p in files}
        assert expected and expected <= names, sorted(expected - names)
    assert "dgsdp/conf/train.yaml" in names and "dgsdp/conf/__init__.py" in names  # pkg://dgsdp.conf needs both
    assert "dgsdp/resources/aistpp_splits/crossmodal_train.txt" in names
    assert "dgsdp/resources/style_prompts/aistpp.yaml" in names and "dgsdp/sweeps/table4.yaml" in names
    assert not [n for n in names if not n.startswith(("dgsdp/", "dgsdp-"))]  # nothing outside the package
    (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    text = zipfile.ZipFile(wheel).read(entry_points).decode()
    section = text.split("[console_scripts]")[1].split("\n[")[0]
    assert {line.split("=")[0].strip() for line in section.splitlines() if "=" in line} == set(SCRIPTS)
    (metadata,) = [n for n in names if n.endswith(".dist-info/METADATA")]
    requires = [line for line in zipfile.ZipFile(wheel).read(metadata).decode().splitlines() if "Requires-Dist" in line]
    runtime = [r for r in requires if "extra ==" not in r]
    assert runtime and not [r for r in runtime if "pytest" in r or "ruff" in r]  # test tools are dev extras only


def _fresh_env(tmp: Path, wheel: Path) -> tuple[Path, dict[str, str]]:
    """A new venv outside the source tree with the wheel installed; it also sees this interpreter's packages (torch,
    lightning, ...: nothing downloads) but not its dgsdp."""
    env_dir = tmp / "env"
    venv.create(env_dir, system_site_packages=True, with_pip=False)
    py = env_dir / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "DGSDP_HOME")}
    env.update(PATH=f"{env_dir / 'bin'}{os.pathsep}{env.get('PATH', '')}", HF_HUB_OFFLINE="1", WANDB_MODE="offline")
    install = [sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "-q", str(wheel)]
    done = subprocess.run(install, capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    # This interpreter's packages, added after the install and as plain path lines (no 'import site'): an
    # editable install of dgsdp here stays inactive, and the wheel's dgsdp comes first on the path.
    own = subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                         capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    parents = [p for p in site.getsitepackages() if Path(p).is_dir()]
    Path(own, "_parent_env.pth").write_text("".join(f"{p}\n" for p in parents))
    return env_dir, env


def _run(args: list[str], cwd: Path, env: dict[str, str], timeout: int = 600) -> str:
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{' '.join(map(str, args))}\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}"
    return done.stdout


def _package_files(package_dir: Path) -> set[Path]:
    return {p for p in package_dir.rglob("*") if p.is_file() and "__pycache__" not in p.parts}


@pytest.mark.slow
def test_installed_wheel_trains_and_generates_from_any_folder(wheel, tmp_path, repo_root):
    env_dir, env = _fresh_env(tmp_path, wheel)
    work = tmp_path / "work"  # an empty folder outside the source tree
    work.mkdir()
    where = _run(["python", "-c", "import dgsdp; print(dgsdp.__file__)"], work, env).strip()
    package_dir = Path(where).parent
    assert package_dir.is_relative_to(env_dir) and not package_dir.is_relative_to(repo_root)
    before = _package_files(package_dir)

    assert "table4: 18 jobs" in _run(["dgsdp-sweep", "--list"], work, env)
    tiny_data = ["+data.synthetic.sequences_per_genre=2", "+data.synthetic.seconds=7", "+data.synthetic.num_ignored=0"]
    out = _run(
        ["dgsdp-train", "debug=tiny", "trainer.max_steps=2", "trainer.limit_val_batches=0", "data.progress=false",
         "callbacks.progress.refresh_rate=0", *tiny_data],
        work, env,
    )  # fmt: skip
    checkpoint = Path(out.split("checkpoint written:")[1].split()[0])
    assert checkpoint.is_file() and checkpoint.is_relative_to(work / "outputs" / "train")
    assert (work / "data" / "synthetic" / "motions").is_dir() and (work / "data" / "cache").is_dir()

    song = sorted((work / "data" / "synthetic" / "wavs").glob("*.wav"))[0]
    out = _run(
        ["dgsdp-generate", f"checkpoint={checkpoint}", f"music={song}", "style=krump", "sampling.steps=2", "seconds=3",
         "device=cpu", "formats=[npy,pkl]", "progress=false"],
        work, env,
    )  # fmt: skip
    written = sorted((work / "outputs" / "generate").rglob(f"{song.stem}.*"))
    assert {p.suffix for p in written} == {".npy", ".pkl"} and all(str(p) in out for p in written)
    assert _package_files(package_dir) == before  # nothing was written inside the installed package
    assert sorted(p.name for p in work.iterdir()) == ["data", "outputs"]
