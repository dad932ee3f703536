"""The README's Python example runs as it stands, in a folder with ``model.ckpt`` and ``song.wav``."""

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from generation.gen_helpers import train_tiny_checkpoint, write_click_song


def readme_example(repo_root: Path) -> str:
    text = (repo_root / "README.md").read_text()
    section = text.split("## Python API", 1)[1].split("\n## ", 1)[0]
    (code,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    return code


def test_the_readme_python_example_runs(repo_root, tmp_path, monkeypatch, capsys):
    checkpoint = train_tiny_checkpoint(tmp_path / "train")
    work = tmp_path / "work"
    work.mkdir()
    shutil.copy(checkpoint, work / "model.ckpt")
    write_click_song(work / "song.wav", 3.0)
    monkeypatch.chdir(work)
    monkeypatch.delenv("DGSDP_HOME", raising=False)
    code = readme_example(repo_root).replace("steps=50", "steps=2")  # the papers' 50 steps, shortened here
    namespace: dict = {}
    exec(compile(code, "README.md (Python API)", "exec"), namespace)
    dance = namespace["dance"]
    assert dance.motion.shape == (1, 90, 151) and dance.joints.shape == (1, 90, 24, 3)
    assert namespace["params"]["poses"].shape == (90, 72) and namespace["params"]["trans"].shape == (90, 3)
    assert {p.name for p in work.iterdir()} >= {"my_dance.npy", "my_dance.bvh", "my_dance.pkl", "data"}
    np.testing.assert_allclose(np.load(work / "my_dance.npy"), dance.motion[0].numpy(), atol=1e-6)
    assert (work / "data" / "cache").is_dir()  # features cached in the working folder, as the CLI does
    assert namespace["papers"].motion.shape == (1, 90, 151)
    assert "(1, 90, 151) (1, 90, 24, 3)" in capsys.readouterr().out
    assert os.getcwd() == str(work)


def test_the_api_is_importable_from_the_package_root():
    import dgsdp
    from dgsdp.generation.pipeline import DanceGenerator
    from dgsdp.trained import load_model

    assert dgsdp.DanceGenerator is DanceGenerator and dgsdp.load_model is load_model
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        dgsdp.nothing  # noqa: B018
