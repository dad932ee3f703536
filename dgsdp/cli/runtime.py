"""What every entry point shares around Hydra: unique run folders, a log file holding what the run printed, and a
clear message for a command-line value that Hydra's override syntax cannot read.

- Run folders are ``<time>_<process id>-<random>`` (resolver ``dgsdp_run_suffix``), so two runs started in the same
  second never share a folder. The suffix is fixed once per process: every interpolation sees the same folder.
- :class:`LogPrintedOutput` (a Hydra callback in ``conf/hydra/default.yaml``) copies what the job prints on
  stdout into the job's log file (``generate.log``, ``train.log``, ...), next to the log records Hydra writes there.
- :func:`check_command_line` parses every override before Hydra does and turns a lexer failure (an unquoted
  non-ASCII letter, space, comma, brackets...) into one message that shows the quoting Hydra needs.
"""

from __future__ import annotations

import logging
import os
import secrets
import shutil
import sys
from pathlib import Path
from typing import Any, TextIO

from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from dgsdp.errors import CheckpointError, ConfigError, DgsdpError

log = logging.getLogger(__name__)

_RUN_SUFFIX = f"{os.getpid()}-{secrets.token_hex(2)}"


def run_suffix() -> str:
    """``<pid>-<4 hex digits>``, the same for the whole process."""
    return _RUN_SUFFIX


if not OmegaConf.has_resolver("dgsdp_run_suffix"):
    OmegaConf.register_new_resolver("dgsdp_run_suffix", run_suffix)


class _Tee:
    """A text stream writing to the original stream and to a log file."""

    def __init__(self, stream: TextIO, log_file: TextIO) -> None:
        self._stream = stream
        self._log_file = log_file

    def write(self, text: str) -> int:
        n = self._stream.write(text)
        try:
            self._log_file.write(text)
            self._log_file.flush()
        except (OSError, ValueError):  # log file gone or closed: keep printing
            pass
        return n

    def flush(self) -> None:
        self._stream.flush()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


class LogPrintedOutput(Callback):
    """Copy the job's stdout into ``<run dir>/<job name>.log`` from job start to job end."""

    def __init__(self) -> None:
        self._saved: TextIO | None = None
        self._file: TextIO | None = None

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        from dgsdp.training.distributed import is_writer

        if not is_writer():  # data-parallel ranks > 0: rank 0 keeps the run's one log
            return
        runtime = config.hydra.runtime
        path = Path(runtime.output_dir) / f"{config.hydra.job.name}.log"
        try:
            self._file = open(path, "a", encoding="utf-8")  # noqa: SIM115 - closed in on_job_end
        except OSError as e:
            log.warning("cannot copy the output into %s: %s", path, e)
            return
        self._saved = sys.stdout
        sys.stdout = _Tee(sys.stdout, self._file)

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        if self._saved is not None:
            sys.stdout.flush()
            sys.stdout = self._saved
            self._saved = None
        if self._file is not None:
            self._file.close()
            self._file = None


QUOTING_HELP = (
    "Hydra reads key=value; a value with spaces, non-ASCII letters or any of ( ) [ ] { } , = ! # ~ & ; ' \" must "
    "be quoted inside the argument"
)


def quoted_override(arg: str) -> str:
    """``key=value`` with the value quoted for Hydra, and the whole argument quoted for a POSIX shell."""
    key, _, value = arg.partition("=")
    if "'" not in value:
        return f"\"{key}='{value}'\""
    escaped = "".join("\\" + c if c in '"\\$`' else c for c in value)
    return f'"{key}=\\"{escaped}\\""'


def check_command_line(argv: list[str] | None = None, prog: str | None = None) -> None:
    """Exit with one clear message (status 2) if an override in ``argv`` (default ``sys.argv[1:]``) is not valid
    Hydra override syntax; Hydra's own message for that is a lexer exception with a caret."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import OverrideParseException

    args = sys.argv[1:] if argv is None else list(argv)
    parser = OverridesParser.create()
    for arg in args:
        if arg.startswith("-") or "=" not in arg:
            continue  # Hydra's own flags (-m, --cfg, ...) and their values
        try:
            parser.parse_overrides([arg])
        except OverrideParseException:
            raise SystemExit(
                f"error: cannot read the command-line setting {arg!r}. {QUOTING_HELP}, e.g. in bash: "
                f"{quoted_override(arg)}"
            ) from None
        except Exception:  # noqa: BLE001 - leave anything else to Hydra's own handling
            continue


def remove_unused_run_folder(folder: str | Path) -> None:
    """Remove a run folder that holds nothing but Hydra's own records (the run stopped before any work)."""
    folder = Path(folder)
    if not folder.is_dir():
        return
    own = {".hydra", f"{HydraConfig.get().job.name}.log"} if HydraConfig.initialized() else {".hydra"}
    if {p.name for p in folder.iterdir()} <= own:
        shutil.rmtree(folder, ignore_errors=True)


def run_main(task: Any, cfg: DictConfig) -> Any:
    """Run an entry point's task with one clear message (and no traceback) for errors a user can meet."""
    try:
        try:
            return task(cfg)
        except InstantiationException as e:  # a constructor's own error (e.g. the datamodule's settings)
            if isinstance(e.__cause__, DgsdpError):
                raise e.__cause__ from None
            raise
    except DgsdpError as e:
        log.error("%s", e)
        if isinstance(e, ConfigError | CheckpointError) and HydraConfig.initialized():
            remove_unused_run_folder(HydraConfig.get().runtime.output_dir)
        raise SystemExit(f"error: {e}") from None
