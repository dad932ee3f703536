"""Blender opens our GLB and BVH files through dgsdp/export/blender_import.py: scene at the dance's FPS and length,
24 bones, keyframes on frames start .. start + N - 1, and the joints where the project's FK puts them.

Slow: it runs Blender as a Python module (``pip install bpy==4.2.0``, Python 3.11) in a subprocess. Point
DGSDP_BPY_PYTHON at a Python that can ``import bpy`` (default: the Python running the tests).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from dgsdp.export import save_bvh, save_glb
from dgsdp.motion import JOINT_NAMES, axis_angle_to_matrix, forward_kinematics, root_rotation_y_up_to_z_up

SCRIPT = Path(__file__).resolve().parents[2] / "dgsdp" / "export" / "blender_import.py"
BPY_PYTHON = os.environ.get("DGSDP_BPY_PYTHON", sys.executable)

# Runs under Blender's Python: imports the file with the helper, then records each bone's head in world space
# (Blender is z-up, metres) at a few frames. It leaves with os._exit: the bpy 4.2.0 module from PyPI crashes while
# shutting down after any glTF import (a segmentation fault after all work is done, with or without this helper).
DRIVER = """
import json, os, sys
sys.path.insert(0, sys.argv[1])
import bpy
import blender_import
dance, audio, frames, out = sys.argv[2], sys.argv[3], json.loads(sys.argv[4]), sys.argv[5]
summary = blender_import.import_dance(dance, audio=audio)
arm = bpy.data.objects[summary["armature"]]
keys = [k.co.x for fc in arm.animation_data.action.fcurves for k in fc.keyframe_points]
counts = {len(fc.keyframe_points) for fc in arm.animation_data.action.fcurves}
heads = {}
scene = bpy.context.scene
for f in frames:
    scene.frame_set(scene.frame_start + f)
    heads[f] = {b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones}
summary.update(key_min=min(keys), key_max=max(keys), key_counts=sorted(counts), heads=heads,
               scene_fps=scene.render.fps, fps_base=scene.render.fps_base)
with open(out, "w") as f:
    f.write(json.dumps(summary))
sys.stdout.flush()
sys.stderr.flush()
os._exit(0)
"""


def dance(frames: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Random joint rotations (about 0.5 rad), upright root travelling 0.9 m above the floor."""
    g = torch.Generator().manual_seed(seed)
    rot = axis_angle_to_matrix(0.5 * torch.randn(frames, 24, 3, generator=g, dtype=torch.float64))
    rot[:, 0] = root_rotation_y_up_to_z_up(rot[:, 0])
    t = torch.arange(frames, dtype=torch.float64)
    return rot, torch.stack((0.03 * t, -0.02 * t, torch.full_like(t, 0.9)), dim=-1)


def _bpy_importable() -> bool:
    try:
        probe = subprocess.run([BPY_PYTHON, "-c", "import bpy"], capture_output=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return probe.returncode == 0


pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        not _bpy_importable(),
        reason=f"bpy is not importable by {BPY_PYTHON}: `pip install bpy==4.2.0` in a Python 3.11 environment and "
        "set DGSDP_BPY_PYTHON to its python",
    ),
]


@pytest.mark.parametrize("suffix", [".glb", ".bvh"])
def test_blender_imports_dance_with_fps_range_and_joints(tmp_path, suffix):
    n = 41
    rot, trans = dance(n, seed=3)
    path = tmp_path / f"dance{suffix}"
    (save_glb if suffix == ".glb" else save_bvh)(path, rot, trans, fps=30)
    song = tmp_path / "song.wav"
    sf.write(song, np.zeros(22050 * 2, np.float32), 22050)
    frames = [0, 17, n - 1]
    out = tmp_path / "summary.json"
    run = subprocess.run(
        [BPY_PYTHON, "-c", DRIVER, str(SCRIPT.parent), str(path), str(song), json.dumps(frames), str(out)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    summary = json.loads(out.read_text())

    start = 0 if suffix == ".glb" else 1
    assert summary["frames"] == n and summary["bones"] == 24
    assert summary["scene_fps"] == 30 and summary["fps_base"] == 1.0 and summary["fps"] == 30
    assert (summary["frame_start"], summary["frame_end"]) == (start, start + n - 1)
    # One key per frame, on frames start .. start + N - 1 (the scene's FPS was set before the import).
    assert summary["key_counts"] == [n]
    assert (summary["key_min"], summary["key_max"]) == pytest.approx((start, start + n - 1), abs=1e-3)
    # The song: a strip at the first frame, or a clear reason where this Blender has no audio support.
    if summary["sound"] is None:
        assert "Audaspace" in summary["sound_error"] and f"frame {start}" in summary["sound_error"]
    else:
        assert summary["sound_error"] is None

    joints = forward_kinematics(rot, trans).numpy()  # z-up metres, as Blender's world
    names = ["pelvis", "left_knee", "right_wrist", "head", "left_foot"]
    for f in frames:
        heads = summary["heads"][str(f)]
        assert len(heads) == 24
        for name in names:
            np.testing.assert_allclose(heads[name], joints[f, JOINT_NAMES.index(name)], atol=1e-3, err_msg=name)
