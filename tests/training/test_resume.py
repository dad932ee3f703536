"""check_resume_has_work: a resume that would train nothing says which limit is reached and how to train on."""

import pytest

from dgsdp.errors import ConfigError
from dgsdp.training.resume import check_resume_has_work


def ckpt(step, epochs_processed):
    return {"global_step": step, "epoch": epochs_processed,
            "loops": {"fit_loop": {"epoch_progress": {"current": {"processed": epochs_processed}}}}}  # fmt: skip


def test_steps_reached():
    with pytest.raises(ConfigError, match=r"step 300 and trainer.max_steps=300; raise trainer.max_steps"):
        check_resume_has_work({"max_steps": 300, "max_epochs": -1}, ckpt(300, 4))
    check_resume_has_work({"max_steps": 301, "max_epochs": -1}, ckpt(300, 4))


def test_epochs_reached():
    with pytest.raises(
        ConfigError, match=r"finished 2000 epochs and trainer.max_epochs=2000; raise trainer.max_epochs"
    ):
        check_resume_has_work({"max_steps": -1, "max_epochs": 2000}, ckpt(10**6, 2000))
    check_resume_has_work({"max_steps": -1, "max_epochs": 2001}, ckpt(10**6, 2000))
    check_resume_has_work({"max_steps": -1, "max_epochs": -1}, ckpt(10**6, 2000))  # -1: no limit


def test_lightning_default_of_1000_epochs():
    with pytest.raises(ConfigError, match="trainer.max_epochs=1000"):
        check_resume_has_work({"max_steps": -1, "max_epochs": None}, ckpt(5, 1000))
    check_resume_has_work({"max_steps": 10, "max_epochs": None}, ckpt(5, 1000))  # steps set: no epoch limit
