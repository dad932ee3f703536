"""data.skeleton: the AIST++-layout data is SMPL-24; another skeleton is one clear error before anything loads."""

import numpy as np
import pytest
from motion_helpers import made_up_smplx_joints

from dgsdp.data.datamodule import DanceDataModule
from dgsdp.errors import ConfigError
from dgsdp.motion import SMPL24


def test_aistpp_layout_is_smpl24(tmp_path):
    dm = DanceDataModule(str(tmp_path), str(tmp_path / "cache"))
    assert dm.skeleton is SMPL24 and dm.normalizer.data_min.shape == (151,)


def test_other_skeletons_are_refused_with_a_clear_error(tmp_path):
    np.save(tmp_path / "joints.npy", made_up_smplx_joints())
    with pytest.raises(ConfigError, match="reads smpl24 motion"):
        DanceDataModule(
            str(tmp_path), str(tmp_path / "cache"), skeleton="smplx22", smplx_file=str(tmp_path / "joints.npy")
        )
    with pytest.raises(ConfigError, match="data.smplx_file.*smpl-x.is.tue.mpg.de"):
        DanceDataModule(str(tmp_path), str(tmp_path / "cache"), skeleton="smplx52")
    with pytest.raises(ConfigError, match="unknown skeleton 'smpl'"):
        DanceDataModule(str(tmp_path), str(tmp_path / "cache"), skeleton="smpl")
