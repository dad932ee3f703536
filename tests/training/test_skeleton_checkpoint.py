"""A run's skeleton is part of its spec: the model's input size follows it, checkpoints record it as plain data,
and checkpoints without one are SMPL-24 runs."""

import copy
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
from gen_helpers import tiny_spec  # noqa: E402
from motion_helpers import made_up_smplx_joints, random_motion  # noqa: E402

from dgsdp.errors import CheckpointError  # noqa: E402
from dgsdp.motion import SMPL24, smplx_skeleton  # noqa: E402
from dgsdp.trained import RunSpec, load_model  # noqa: E402
from dgsdp.training import DanceDiffusion  # noqa: E402


@pytest.fixture(scope="module")
def smplx52(tmp_path_factory):
    path = tmp_path_factory.mktemp("smplx") / "joints.npy"
    np.save(path, made_up_smplx_joints())
    return smplx_skeleton("full52", path)


def checkpoint(spec):
    torch.manual_seed(0)
    model = DanceDiffusion(spec).eval()
    model.normalizer.fit(random_motion(50, num_joints=spec.skeleton.num_joints))
    return model, {"state_dict": model.state_dict(), "hyper_parameters": model.spec.to_dict(), "dgsdp_format": 2}


def test_the_model_reads_and_writes_the_skeletons_pose_vectors(smplx52, tmp_path):
    spec = dataclasses.replace(tiny_spec(), skeleton=smplx52)
    model, ckpt = checkpoint(spec)
    assert model.skeleton == smplx52 and model.normalizer.data_min.shape == (7 + 6 * 52,)
    assert model.denoiser.input_proj.in_features == model.denoiser.output_proj.out_features == 319
    stored = ckpt["hyper_parameters"]["skeleton"]
    assert json.loads(json.dumps(stored)) == stored and stored["name"] == "smplx52"
    torch.save(ckpt, tmp_path / "x.ckpt")
    loaded = load_model(tmp_path / "x.ckpt")
    assert loaded.skeleton == smplx52 and loaded.spec == spec
    assert torch.equal(loaded.normalizer.data_max, model.normalizer.data_max)
    x = torch.randn(2, spec.window_frames, 319)
    out = loaded.denoiser(
        x, torch.zeros(2, dtype=torch.long), torch.zeros(2, spec.window_frames, 35), torch.zeros(2, 10)
    )
    assert out.shape == x.shape


def test_a_checkpoint_without_a_skeleton_is_an_smpl24_run(tmp_path):
    _, ckpt = checkpoint(tiny_spec())
    assert ckpt["hyper_parameters"]["skeleton"] == SMPL24.to_dict()
    old = copy.deepcopy(ckpt)
    del old["hyper_parameters"]["skeleton"]  # as written before skeletons were data
    torch.save(old, tmp_path / "old.ckpt")
    model = load_model(tmp_path / "old.ckpt")
    assert model.skeleton is SMPL24 and model.denoiser.input_proj.in_features == 151
    assert RunSpec.from_dict(old["hyper_parameters"]) == RunSpec.from_dict(ckpt["hyper_parameters"])


def test_a_bad_or_mismatched_skeleton_is_refused(smplx52, tmp_path):
    _, ckpt = checkpoint(tiny_spec())
    bad = copy.deepcopy(ckpt)
    bad["hyper_parameters"]["skeleton"]["parents"][5] = 40
    torch.save(bad, tmp_path / "bad.ckpt")
    with pytest.raises(CheckpointError, match="bad.ckpt.*skeleton"):
        load_model(tmp_path / "bad.ckpt")
    other = copy.deepcopy(ckpt)  # SMPL-24 weights under an SMPL-X record: the weights' shapes do not match it
    other["hyper_parameters"]["skeleton"] = smplx52.to_dict()
    torch.save(other, tmp_path / "other.ckpt")
    with pytest.raises(CheckpointError, match="input_proj.weight"):
        load_model(tmp_path / "other.ckpt")
    with pytest.raises(CheckpointError, match="skeleton"):
        RunSpec.from_dict(ckpt["hyper_parameters"]).check_resumable_with(
            dataclasses.replace(tiny_spec(), skeleton=smplx52), "run.ckpt"
        )
