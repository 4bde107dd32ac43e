"""The HTTP client behind `ravenmem search/ask/info --server URL`: a warm service answers
instead of a cold process, with the same JSON (`image` is then a URL, not a file path).

Only httpx (already a dependency of the agent's OpenAI client) is needed, not the web stack.
The token comes from `RAVENMEM_TOKEN`; errors are one-line `InputError`s naming the service.
"""

from __future__ import annotations

import base64
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import InputError
from ..fsio import MAX_IMAGE, read_bounded
from ..tools import Tool, ToolArgs

if TYPE_CHECKING:  # (the agent is imported only by a command that asks)
    from ..runtime.ask import AskArgs

ENV_SERVER = "RAVENMEM_SERVER"
ENV_TOKEN = "RAVENMEM_TOKEN"


def resolve_server(server: str | None, memory: Path | None) -> str | None:
    """Which service answers: `--server`, else $RAVENMEM_SERVER when no `--memory` is given.

    Returns None when the command should open the memory itself. Both `--server` and
    `--memory` is a contradiction (one line, exit 2); neither is one too.
    """
    if server and memory is not None:
        raise InputError("give --memory (open it here) or --server (ask a running service), not both")
    url = server or (os.environ.get(ENV_SERVER) if memory is None else None)
    if not url and memory is None:
        raise InputError(
            f"Missing option '--memory': give --memory DIR, or --server URL (or set {ENV_SERVER}); see --help"
        )
    return url or None


class ServerClient:
    """A running `ravenmem serve`, by URL, with the methods of a memory opened here
    (`cli.source.LocalSource`): `info`, `search`, `ask_json`, `picture`, `t0`, `where`."""

    def __init__(self, url: str, token: str | None = None, timeout: float = 600.0) -> None:
        import httpx

        if not url.startswith(("http://", "https://")):
            raise InputError(f"--server must be an http:// or https:// URL, got {url!r}")
        self.url = url.rstrip("/")
        self.where = self.url
        token = token if token is not None else os.environ.get(ENV_TOKEN)
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> ServerClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _call(self, method: str, path: str, **kw: Any) -> Any:
        import httpx

        try:
            r = self._http.request(method, path, **kw)
        except httpx.HTTPError as e:
            raise InputError(f"cannot reach the ravenmem service at {self.url}: {e}") from None
        try:
            body = r.json()
        except ValueError:
            body = None
        if r.status_code >= 400:
            msg = body.get("error") if isinstance(body, dict) else None
            if isinstance(body, dict) and isinstance(body.get("answer"), dict):  # a refused question
                from ..agent.ask import QuestionFailed

                raise QuestionFailed(str(msg), body["answer"], r.status_code)
            raise InputError(f"service {self.url}: {msg or f'HTTP {r.status_code}'}")
        return body

    def info(self) -> dict[str, Any]:
        return dict(self._call("GET", "/info"))

    def t0(self) -> float | None:
        """(Times are shown as the service gives them; no local reference.)"""
        return None

    def search(self, tool: Tool, args: ToolArgs, k: int, image: Path | None = None) -> list[dict[str, Any]]:
        """One tool call's hits, as `ravenmem search --json` prints them (`image` uploads a
        query picture); their pictures as URLs."""
        return list(self.search_json(tool, args, k, image)["results"])

    def search_json(self, tool: Tool, args: ToolArgs, k: int, image: Path | None = None) -> dict[str, Any]:
        """One tool call, as the service answers it (`image` uploads a query picture)."""
        params: list[tuple[str, str | int | float]] = [("k", k)]
        for name, value in args.model_dump(exclude_none=True).items():
            for v in value if isinstance(value, list) else [value]:
                params.append((name, v))
        if image is None:
            return dict(self._call("GET", f"/search/{tool.key}", params=params))
        data = _read(image)
        files = {"image": (image.name, data, "application/octet-stream")}
        return dict(self._call("POST", f"/search/{tool.key}", params=params, files=files))

    def ask(self, args: AskArgs, image: Path | None = None) -> dict[str, Any]:
        """A question (the one request, `AskArgs`), answered as `ravenmem ask --json` prints it
        (evidence images as URLs); `image` uploads a query picture. A question the service
        refused (failed, unsupported) raises `QuestionFailed` with the answer."""
        body = args.given()
        if image is not None:
            body["image"] = base64.b64encode(_read(image)).decode()
        return dict(self._call("POST", "/ask", json=body))

    def ask_json(self, args: AskArgs, image: Path | None = None) -> tuple[dict[str, Any], str | None, int]:
        """`ask`, with a refused question as its answer, the refusal and exit 1 (evidence
        pictures named under `image_file` too, as a local answer names them)."""
        from ..agent.ask import QuestionFailed

        try:
            data, refusal = self.ask(args, image), None
        except QuestionFailed as e:
            if e.answer is None:
                raise
            data, refusal = e.answer, str(e)
        for ev in data["evidence"]:
            ev["image_file"] = ev.get("image")
        return data, refusal, 1 if refusal else 0

    def picture(self, memory_id: int) -> bytes | None:
        """A memory's stored picture as the service sends it (JPEG/PNG bytes), or None when the
        memory has none the service may serve (the contact sheets of `--server` use it)."""
        import httpx

        try:
            r = self._http.get(f"/memories/{int(memory_id)}/image")
        except httpx.HTTPError as e:
            raise InputError(f"cannot reach the ravenmem service at {self.url}: {e}") from None
        return r.content if r.status_code == 200 else None


def _read(path: Path) -> bytes:
    """A query picture's bytes, bounded (`/dev/zero` is one line, not a read without end)."""
    return read_bounded(path, MAX_IMAGE, "image file")
