"""Runs several entry points in one fresh interpreter, as ``python <script>`` / ``python -m <module>`` would run
them (``runpy``, ``__main__``), so that the heavy imports are paid once. Usage:

    python cli_driver.py <results.json> <jobs.json>

jobs.json: a list of {"name", "script" or "module" or "entry" ("module:function", a console script's target) or
"exec" (a Python file run as a snippet), "argv"}, each optionally with "cwd" (the folder it runs in), "env" (variables
set while it runs), "path" (folders put first on sys.path) and "globs" ({"<word>": "pattern"}: each word of argv
replaced by the name of the newest path matching the pattern in cwd, when the job starts). results.json gets, per name, the exit
code (0 when the entry point returns, the SystemExit code otherwise, a text on any other exception) and what it
wrote to stdout and stderr, the seconds it took and the CPU seconds this process spent on it.
"""

import contextlib
import importlib
import io
import json
import os
import runpy
import sys
import time
import traceback
from pathlib import Path


@contextlib.contextmanager
def _place(job: dict):
    """The job's folder, variables and import path while it runs; all restored afterwards."""
    cwd, env, path = os.getcwd(), dict(os.environ), list(sys.path)
    try:
        if job.get("cwd"):
            os.chdir(job["cwd"])
        os.environ.update(job.get("env", {}))
        sys.path[:0] = [os.path.abspath(p) for p in job.get("path", [])]
        yield
    finally:
        os.chdir(cwd)
        os.environ.clear()
        os.environ.update(env)
        sys.path[:] = path


def _argv(job: dict) -> list[str]:
    """argv with each word of ``globs`` replaced by the name of the newest path matching its pattern (in the job's
    folder)."""
    argv = list(job["argv"])
    for word, pattern in job.get("globs", {}).items():
        matches = sorted(Path().glob(pattern), key=lambda p: p.stat().st_mtime)
        if matches:
            argv = [a.replace(word, matches[-1].name) for a in argv]
    return argv


def _start(job: dict) -> None:
    if "script" in job:
        runpy.run_path(job["script"], run_name="__main__")
    elif "exec" in job:
        runpy.run_path(job["exec"], run_name="__snippet__")
    elif "entry" in job:
        module, _, function = job["entry"].partition(":")
        result = getattr(importlib.import_module(module), function)()
        if result:
            raise SystemExit(result)
    else:
        runpy.run_module(job["module"], run_name="__main__", alter_sys=True)


def run(job: dict) -> dict:
    out, err = io.StringIO(), io.StringIO()
    target = job.get("script") or job.get("module") or job.get("entry") or job["exec"]
    code: int | str = 0
    start, cpu_start = time.perf_counter(), time.process_time()
    with _place(job), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            sys.argv = [target, *_argv(job)]
            _start(job)
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
