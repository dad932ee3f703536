"""benchmarks.gpu, the one prepared run of the GPU figures, tried on the CPU (its dry run)."""

import pytest

from dgsdp.benchmarks import gpu
from dgsdp.data.synthetic import generate_synthetic_aistpp


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    base = tmp_path_factory.mktemp("gpu") / "data"
    return generate_synthetic_aistpp(base / "synthetic", seed=0, sequences_per_genre=2, seconds=7.0, num_ignored=0)


@pytest.mark.slow  # times both loaders on a generated dataset (about 12 s); run it before a device session
# (pytest -m slow tests/benchmarks/test_gpu_script.py); the failing-step test runs the same steps and summary
def test_the_data_step_and_its_summary(root, tmp_path, capsys):
    code = gpu.main(["--device", "cpu", "--data", str(root), "--out", str(tmp_path), "--skip", "training", "train"])
    out = capsys.readouterr().out
    assert code == 0
    summary = out.split("=== summary (CPU)")[1]
    assert "data: exit 0" in summary and "ms per batch: host loader" in summary
    assert "ms per batch" in (tmp_path / "data.log").read_text()


def test_a_failing_step_is_reported_and_the_run_goes_on(tmp_path, capsys):
    (tmp_path / "a_file").write_text("")
    unwritable = tmp_path / "a_file" / "synthetic"  # the dataset cannot be generated there
    code = gpu.main(["--device", "cpu", "--data", str(unwritable), "--out", str(tmp_path), "--skip", "training",
                     "train"])  # fmt: skip
    summary = capsys.readouterr().out.split("=== summary (CPU)")[1]
    assert code == 1 and "data: exit 1" in summary


def test_profile_rows_are_picked_from_lightnings_table():
    table = (
        "|  Action   \t|  Mean duration (s)\t|\n"
        "|  Total    \t|  -              \t|  30  \t|  12.5  \t|  100 %\t|\n"
        "|  run_training_batch   \t|  0.07  \t|  100  \t|  7.0  \t|  56 %\t|\n"
        "|  [Callback]TQDMProgressBar.on_train_batch_end   \t|  0.001  \t|\n"
    )
    picked = [line.split("|")[1].strip() for line in table.splitlines() if gpu.PROFILE_ROWS.match(line)]
    assert picked == ["Total", "run_training_batch"]


@pytest.mark.slow
def test_the_training_steps_give_steps_per_second_and_a_profile(root, tmp_path, capsys):
    code = gpu.main(["--device", "cpu", "--data", str(root), "--out", str(tmp_path), "--skip", "training", "data",
                     "--steps", "4", "40", "--profile-steps", "4"])  # fmt: skip
    summary = capsys.readouterr().out.split("=== summary (CPU)")[1]
    assert code == 0
    assert "quickstart_row12 training:" in summary and "steps/s (4 and 40 steps)" in summary
    assert "run_training_batch" in summary
