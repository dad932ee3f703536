"""Which login may read which of the studio's files: with logins, each login's dances and uploads are its own.

A studio with logins writes each login's dances under ``<work-dir>/runs/<login folder>/`` and records which login
sent each upload. :class:`LoginFiles` sits in front of Gradio's routes: its file routes (``/gradio_api/file=...``
and the older ``/gradio_api/file/...``) serve a file of the studio's folders (the work folder and Gradio's upload
folder) only to the login it belongs to, and answer everything else with Gradio's own refusal, the same whether or
not the file exists. The example songs are every login's. Without logins the studio has one user and nothing here
is checked.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import threading
from collections.abc import Awaitable, Callable, Iterable, MutableMapping
from pathlib import Path
from typing import Any

from dgsdp.errors import ConfigError

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

LOGIN_PREFIX = "login-"  # a login's folder under runs/; run folders start with their date
FILE_ROUTES = ("/gradio_api/file=", "/gradio_api/file/", "/file=", "/file/")  # the last two: older Gradio paths
UPLOAD_ROUTES = ("/gradio_api/upload", "/upload")


def login_folder_name(login: str) -> str:
    """The folder of one login's dances under ``runs/``: the login in safe characters (for whoever reads the disk)
    and a digest of it (so two logins never share a folder)."""
    readable = re.sub(r"[^A-Za-z0-9_-]+", "_", login).strip("_")[:32]
    return f"{LOGIN_PREFIX}{readable}-{hashlib.sha256(login.encode()).hexdigest()[:12]}"


class FileAccess:
    """The owners of a studio's files: a dance by the login folder it is written in, an upload by the login that sent
    it (kept in memory: after a restart, songs are uploaded again), an example song by every login."""

    def __init__(self, work_dir: Path, upload_dir: Path) -> None:
        self.work_dir = Path(work_dir).resolve()
        self.upload_dir = Path(upload_dir).resolve()
        self.examples = self.work_dir / "examples"
        # both spellings of each folder: a path is checked as written and with its links resolved
        self._roots = {
            self.work_dir,
            self.upload_dir,
            Path(os.path.abspath(work_dir)),
            Path(os.path.abspath(upload_dir)),
        }
        self._uploads: dict[Path, set[str]] = {}
        self._lock = threading.Lock()

    def runs_folder(self, login: str | None) -> Path:
        """Where a login's dances go: ``runs/<login folder>`` (``runs`` itself without logins, ``login`` None)."""
        runs = self.work_dir / "runs"
        if login is None:
            return runs
        if not login:
            raise ConfigError("this studio needs a login: reload the page and log in")
        return runs / login_folder_name(login)

    def record_uploads(self, login: str, paths: Iterable[str]) -> None:
        """Note ``login`` as an owner of each uploaded path (two logins uploading the same song share its path)."""
        with self._lock:
            for path in paths:
                self._uploads.setdefault(Path(os.path.realpath(path)), set()).add(login)

    def forget_removed(self) -> None:
        """Drop the records of uploads that are gone (removed by the studio's retention)."""
        with self._lock:
            self._uploads = {path: owners for path, owners in self._uploads.items() if path.exists()}

    def may_use(self, login: str | None, path: str | Path) -> bool:
        """Whether ``login`` may read ``path``: its own dances and uploads, and the example songs (everything when
        ``login`` is None: a studio without logins, or a call from this process)."""
        if login is None:
            return True
        real = Path(os.path.realpath(path))
        if real.is_relative_to(self.examples):
            return True
        if login and real.is_relative_to(self.runs_folder(login)):
            return True
        with self._lock:
            return login in self._uploads.get(real, ())

    def guarded(self, path: Path) -> bool:
        """Whether ``path`` lies in one of the studio's folders (the work folder, the upload folder)."""
        return any(path.is_relative_to(root) for root in self._roots)

    def may_serve(self, login: str, target: str) -> bool:
        """Whether a file route may serve ``target`` (the path as the client wrote it) to ``login`` ('' for a request
        without one). Paths outside the studio's folders are left to Gradio's own checks."""
        if re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", target):  # a URL: Gradio fetches public ones, no file of ours
            return True
        try:
            written, real = Path(os.path.abspath(target)), Path(os.path.realpath(target))
        except (OSError, ValueError):  # e.g. a NUL byte: Gradio refuses it too
            return False
        if not (self.guarded(written) or self.guarded(real)):
            return True
        return bool(login) and self.may_use(login, real)


def route_path(scope: Scope) -> str:
    """The request's path as Gradio's routes match it (decoded, without the app's root path)."""
    path, root = scope.get("path", ""), scope.get("root_path", "")
    if root and path.startswith(root) and path[len(root) : len(root) + 1] in ("", "/"):
        return path[len(root) :]
    return path


def file_route_target(path: str) -> str | None:
    """The file a file route is asked for (as written in the request), or None for any other route."""
    for prefix in FILE_ROUTES:
        if path.startswith(prefix):
            return path[len(prefix) :]
    return None


def request_login(scope: Scope) -> str | None:
    """The login of a request, read as Gradio reads it: the access-token cookie of the Gradio app serving it."""
    app = scope.get("app")
    cookie_id, tokens = getattr(app, "cookie_id", None), getattr(app, "tokens", None)
    if cookie_id is None or not isinstance(tokens, dict):
        return None
    from starlette.requests import HTTPConnection

    cookies = HTTPConnection(scope).cookies
    token = cookies.get(f"access-token-{cookie_id}") or cookies.get(f"access-token-unsecure-{cookie_id}")
    return tokens.get(token) if token else None


class LoginFiles:
    """ASGI middleware of a studio with logins: the file routes serve each login only its own files of the studio's
    folders, and each upload is recorded to the login that sent it before the answer (its stored path) goes out."""

    def __init__(self, app: ASGIApp, access: FileAccess) -> None:
        self.app = app
        self.access = access

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = route_path(scope)
        target = file_route_target(path)
        if target is not None and not self.access.may_serve(request_login(scope) or "", target):
            from starlette.responses import JSONResponse

            # Gradio's answer for a file it does not serve, missing or not
            await JSONResponse({"detail": f"File not allowed: {target}."}, status_code=403)(scope, receive, send)
            return
        if target is None and scope.get("method") == "POST" and path.rstrip("/") in UPLOAD_ROUTES:
            login = request_login(scope)
            if login:
                send = self._recording(send, login)
        await self.app(scope, receive, send)

    def _recording(self, send: Send, login: str) -> Send:
        """``send`` that records the stored paths of a successful upload to ``login`` before its answer ends."""
        status, body = 0, bytearray()

        async def wrapped(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            elif message["type"] == "http.response.body":
                body.extend(message.get("body", b""))
                if status == 200 and not message.get("more_body", False):
                    self.access.record_uploads(login, _stored_paths(bytes(body)))
            await send(message)

        return wrapped


def _stored_paths(body: bytes) -> list[str]:
    """The paths of an upload answer (a JSON list of paths); [] for anything else."""
    try:
        value = json.loads(body)
    except ValueError:
        return []
    return [p for p in value if isinstance(p, str)] if isinstance(value, list) else []
