"""Who may talk to the service: loopback without a token, anything else only with one."""

from __future__ import annotations

from functools import partial
from pathlib import Path

import httpx
import pytest

from ravenmem.server.security import check_bind, is_loopback
from tests.cli.helpers import run_cli as _run_cli
from tests.server.conftest import TOKEN, Served

REPO = Path(__file__).resolve().parents[2]


def every_route(served: Served) -> list[tuple[str, str]]:
    """(method, path) of every route that touches the memory, from the app's own OpenAPI."""
    spec = httpx.get(f"{served.url}/openapi.json").json()  # public: the API description only
    out = []
    for path, ops in spec["paths"].items():
        for method in ops:
            out.append((method.upper(), path.replace("{memory_id}", "1")))
    out += [("GET", "/memories/1/image"), ("POST", "/mcp"), ("GET", "/events")]
    return sorted(set(out))


def test_with_a_token_every_route_needs_the_bearer(served_token: Served):
    routes = every_route(served_token)
    assert ("GET", "/search/text") in routes and ("POST", "/memories") in routes and len(routes) >= 12
    for method, path in routes:
        for headers in ({}, {"Authorization": "Bearer wrong-token-wrong-token"}, {"Authorization": TOKEN}):
            r = httpx.request(method, served_token.url + path, headers=headers, timeout=10)
            assert r.status_code == 401, (method, path, headers, r.status_code)
            assert r.json() == {"error": "missing or wrong bearer token (send Authorization: Bearer <token>)"}
            assert r.headers["www-authenticate"] == "Bearer"
    assert served_token.mem.count() == 12  # nothing was added by the refused POSTs


def test_with_the_token_the_routes_answer(served_token: Served):
    with served_token.client(TOKEN) as c:
        assert c.get("/health").status_code == 200
        hits = c.get("/search/text", params={"q": "red", "k": 1}).json()["results"]
        assert c.get(hits[0]["image"]).status_code == 200
        with c.stream("GET", "/events") as r:
            assert r.status_code == 200
            assert next(r.iter_lines()) == "event: hello"
    # the page itself (no data in it) loads without the header; its API calls need it
    assert httpx.get(served_token.url + "/").status_code == 200
    assert httpx.get(served_token.url + "/static/app.js").status_code == 200
    assert httpx.get(served_token.url + "/memories/1/image").status_code == 401
    spec = httpx.get(served_token.url + "/openapi.json").json()  # /docs offers to send the token
    assert (
        spec["security"] == [{"bearer": []}]
        and spec["components"]["securitySchemes"]["bearer"]["scheme"] == "bearer"
    )


def test_loopback_without_token_refuses_other_host_names_and_origins(served: Served):
    with served.client() as c:
        assert c.get("/health").status_code == 200
        assert (
            c.get("/health", headers={"Host": f"localhost:{served.url.rsplit(':', 1)[1]}"}).status_code == 200
        )
        rebinding = c.get("/info", headers={"Host": "evil.example.com"})
        assert rebinding.status_code == 403 and "loopback" in rebinding.json()["error"]
        cross = c.post(
            "/memories",
            headers={"Origin": "http://evil.example.com"},
            files={"image": ("f.png", b"x", "image/png")},
            data={"x": "1", "y": "1"},
        )
        assert cross.status_code == 403 and "origin" in cross.json()["error"]
        same = c.get("/health", headers={"Origin": served.url})
        assert same.status_code == 200
    assert served.mem.count() == 12


def test_no_cors_headers(served: Served):
    r = httpx.options(
        served.url + "/search/text",
        headers={"Origin": served.url, "Access-Control-Request-Method": "GET"},
    )
    assert "access-control-allow-origin" not in r.headers


@pytest.mark.parametrize(
    ("host", "token", "ok"),
    [
        ("127.0.0.1", None, True),
        ("localhost", None, True),
        ("::1", None, True),
        ("127.0.0.5", None, True),
        ("0.0.0.0", None, False),
        ("192.168.1.10", None, False),
        ("::", None, False),
        ("0.0.0.0", "short", False),
        ("0.0.0.0", TOKEN, True),
    ],
)
def test_check_bind(host, token, ok):
    if ok:
        check_bind(host, token)
    else:
        with pytest.raises(Exception, match="token"):
            check_bind(host, token)
    assert is_loopback(host) == (host in ("127.0.0.1", "localhost", "::1", "127.0.0.5"))


run_cli = partial(_run_cli, timeout=120, unset=("RAVENMEM_TOKEN",))


def test_serve_refuses_a_public_address_without_a_token(tmp_path):
    r = run_cli("serve", "--memory", str(tmp_path / "none.mem"), "--host", "0.0.0.0")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "without a token" in lines[0] and "Traceback" not in r.stderr
    r = run_cli(
        "serve", "--memory", str(tmp_path / "none.mem"), "--host", "0.0.0.0", env={"RAVENMEM_TOKEN": "abc"}
    )
    assert r.returncode == 2 and "at least 16" in r.stderr
    r = run_cli("serve", "--memory", str(tmp_path / "none.mem"), "--port", "0")
    assert r.returncode == 2 and "does not exist (pass --create" in r.stderr and "Traceback" not in r.stderr


def test_serve_says_when_the_port_is_taken(tmp_path):
    import socket

    from tests.server.conftest import make_memory

    make_memory(tmp_path / "m.mem").close()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        r = run_cli("serve", "--memory", str(tmp_path / "m.mem"), "--port", str(port))
    assert (
        r.returncode == 2 and f"cannot listen on 127.0.0.1:{port}" in r.stderr and "Traceback" not in r.stderr
    )


def test_the_listening_socket_is_tcp_so_responses_are_not_delayed():
    """asyncio turns Nagle's algorithm off only on sockets whose protocol says TCP; a socket made
    with protocol 0 left every response waiting ~40 ms for the client's delayed ACK."""
    import socket

    from ravenmem.server.run import listen

    server = listen("127.0.0.1", 0)
    try:
        client = socket.create_connection(server.getsockname()[:2])
        conn, _ = server.accept()
        with client, conn:
            assert server.proto == socket.IPPROTO_TCP and conn.proto == socket.IPPROTO_TCP
    finally:
        server.close()


def test_serve_with_a_vlm_method_and_no_vlm_refuses_to_start(tmp_path):
    """`--method raven` (or vlm-only, caption) without a model stops the start with one line, as
    `ravenmem eval` does, rather than serving a default that fails every question."""
    from tests.eval.eval_helpers import no_vlm_env
    from tests.server.conftest import make_memory

    make_memory(tmp_path / "m.mem").close()
    for method in ("raven", "vlm-only", "caption"):
        r = run_cli(
            "serve",
            "--memory",
            str(tmp_path / "m.mem"),
            "--port",
            "0",
            "--method",
            method,
            env=no_vlm_env(tmp_path),
        )
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip().splitlines() == [
            f"error: --method {method} needs a VLM and none is configured: give --model and --base-url, "
            "or set RAVENMEM_VLM_MODEL / RAVENMEM_VLM_BASE_URL"
        ]
