"""Lightning's log lines print once, whether logging is configured by Hydra's job logging or by basicConfig.

Each case runs in a fresh Python: logging state is global, and Lightning installs its handlers at import."""

import subprocess
import sys
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[2]

EMIT = """
import logging
for name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.seed", "lightning"):
    logging.getLogger(name).info("line from %s", name)
"""


def run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=PROJECT_ROOT,
    )  # fmt: skip


def count_lines(out: subprocess.CompletedProcess) -> dict[str, int]:
    text = out.stdout + out.stderr
    names = ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.seed", "lightning")
    return {name: sum(line.endswith(f"line from {name}") for line in text.splitlines()) for name in names}


def test_basic_config_then_lightning_prints_once():
    code = (
        """
import logging, sys
logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stdout)
from dgsdp.utils.logs import lightning_logs_through_root
lightning_logs_through_root()
"""
        + EMIT
    )
    out = run(code)
    assert out.returncode == 0, out.stderr
    assert count_lines(out) == dict.fromkeys(count_lines(out), 1), out.stdout + out.stderr


def test_hydra_job_logging_prints_once_and_writes_the_log_file(tmp_path):
    log_file = tmp_path / "train.log"
    code = (
        f"""
import logging.config
import lightning  # imported before logging is configured, as by the entry points
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from dgsdp.cli.config import CONFIG_DIR
with initialize_config_dir(str(CONFIG_DIR), version_base=None):
    cfg = compose("train", return_hydra_config=True)
job_logging = cfg.hydra.job_logging
OmegaConf.set_struct(job_logging, False)
job_logging.handlers.file.filename = {str(log_file)!r}
logging.config.dictConfig(OmegaConf.to_container(job_logging, resolve=True))
"""
        + EMIT
    )
    out = run(code)
    assert out.returncode == 0, out.stderr
    assert set(count_lines(out).values()) == {1}, out.stdout + out.stderr
    written = log_file.read_text()
    assert all(f"line from {name}" in written for name in count_lines(out))
