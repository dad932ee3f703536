"""Runs several entry points in one fresh interpreter, as ``python <script>`` / ``python -m <module>`` would run
them (``runpy``, ``__main__``), so that the heavy imports are paid once. Usage:

    python cli_driver.py <results.json> <jobs.json>

jobs.json: a list of {"name", "script" or "module", "argv"}. results.json gets, per name, the exit code
(0 when the entry point returns, the SystemExit code otherwise, a text on any other exception) and what it wrote
to stdout and stderr, the seconds it took and the CPU seconds this process spent on it.
"""

import contextlib
import io
import json
import runpy
import sys
import time
import traceback


def run(job: dict) -> dict:
    out, err = io.StringIO(), io.StringIO()
    target = job.get("script") or job["module"]
    sys.argv = [target, *job["argv"]]
    code: int | str = 0
    start, cpu_start = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            if "script" in job:
                runpy.run_path(job["script"], run_name="__main__")
            else:
                runpy.run_module(job["module"], run_name="__main__", alter_sys=True)
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else str(e.code))
        except BaseException:  # noqa: BLE001 - reported to the test
            code = traceback.format_exc()
    try:  # a Hydra app leaves its global state behind when it exits early (--help)
        from hydra.core.global_hydra import GlobalHydra

        GlobalHydra.instance().clear()
    except ImportError:
        pass
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    return {
        "code": code,
        "stdout": out.getvalue(),
        "stderr": err.getvalue(),
        "seconds": seconds,
        "cpu_seconds": cpu_seconds,
    }


if __name__ == "__main__":
    results_path, jobs_path = sys.argv[1:3]
    with open(jobs_path) as f:
        jobs = json.load(f)
    results = {job["name"]: run(job) for job in jobs}
    with open(results_path, "w") as f:
        json.dump(results, f)
