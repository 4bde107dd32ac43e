"""Answers that refuse to invent a place: a model position farther than the threshold from every
memory shown is `unsupported` (with the distance); `ask --navigate`, `POST /ask` (with or
without navigation), MCP `ask` and the robot links do not drive there unless the caller allows
it, and a failed question over HTTP is a non-2xx with its one-line reason."""

from __future__ import annotations

import json

import pytest

from ravenmem.agent import VLMConfig
from tests.agent.conftest import run_cli
from tests.agent.scripted_server import ScriptedModel, answer, tool
from tests.agent.test_ask_navigate import with_map
from tests.agent.test_cli import ids_of

FAR = [30.0, -10.0, 0.5]  # 23.6 m from the nearest memory shown by search_time(+70), m11 at (11, 4)


def invented(ids: dict[int, int]) -> list[dict]:
    """The model searches, is shown memories 7-11, then answers with a place it never saw."""
    return [
        tool("search_time", time="+70"),
        answer(question_type="position", answer="Over there.", evidence=[ids[7]], position=FAR),
    ]


@pytest.fixture
def cli(color_plugin, tmp_path):
    home = tmp_path / "home"
    return lambda *args, **kw: run_cli(*args, site=color_plugin, home=home, **kw)


def vlm(srv) -> tuple[str, ...]:
    return ("--base-url", srv.base_url, "--model", "scripted-vlm")


def test_ask_navigate_does_not_drive_to_an_invented_place(cli, mem_path):
    mem = str(with_map(mem_path))
    ids = ids_of(mem_path)
    with ScriptedModel(invented(ids)) as srv:
        r = cli("ask", "Where is the magenta box?", "-m", mem, *vlm(srv), "--navigate", "--json")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    line = r.stderr.strip()
    assert line.startswith("unsupported answer: its position is ") and "m from every memory" in line, line
    assert "\n" not in line
    data = json.loads(r.stdout)
    assert data["unsupported"] is True and data["support_distance"] == pytest.approx(23.6, abs=0.05)
    nav = data["navigation"]
    assert (
        nav["ok"] is False
        and nav["problem"] == "answer"
        and nav["waypoints"] == []
        and nav["pose_stamped"] is None
    )
    assert nav["reason"].startswith("unsupported answer: its position is 23.6 m")  # goal_for refused it
    assert data["refusal"] == line
    # the card says so too, and without --navigate the question is refused the same way
    with ScriptedModel(invented(ids)) as srv:
        r = cli("ask", "Where is the magenta box?", "-m", mem, *vlm(srv))
    assert (
        r.returncode == 1 and "UNSUPPORTED" in r.stdout and "23.6 m from the nearest memory shown" in r.stdout
    )
    assert r.stderr.strip().startswith("unsupported answer:")


def test_allow_unsupported_plans_the_path_and_a_wider_threshold_supports_it(cli, mem_path):
    mem = str(with_map(mem_path))
    ids = ids_of(mem_path)
    with ScriptedModel(invented(ids)) as srv:
        r = cli(
            "ask",
            "Where is the magenta box?",
            "-m",
            mem,
            *vlm(srv),
            "--navigate",
            "--json",
            "--allow-unsupported",
        )
    data = json.loads(r.stdout)
    assert data["unsupported"] is True and "refusal" not in data
    assert data["navigation"]["problem"] != "answer"  # a plan was made (to the snapped goal, or a reason)
    assert r.returncode == (0 if data["navigation"]["ok"] else 1)
    with ScriptedModel(invented(ids)) as srv:
        r = cli(
            "ask", "Where is the magenta box?", "-m", mem, *vlm(srv), "--json", "--max-position-offset", "30"
        )
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["unsupported"] is False


class Link:
    """A robot link as the service sees one: it is told the answers it may drive to."""

    def __init__(self) -> None:
        self.answers: list[dict] = []

    def on_answer(self, data: dict) -> None:
        self.answers.append(data)

    def describe(self) -> dict:
        return {"kind": "test"}

    def close(self) -> None:
        pass


def test_post_ask_refuses_an_invented_place_and_the_robot_link_is_not_told(tmp_path):
    from tests.server.conftest import make_memory, serve_memory

    mem = make_memory(tmp_path / "m.mem")
    mem_path = mem.path
    ids = {r.frame_index: r.id for r in mem.all_records()}
    with ScriptedModel(invented(ids) * 3) as srv:
        cfg = VLMConfig(base_url=srv.base_url, model="scripted", api_key="k", timeout=5, max_retries=0)
        for s in serve_memory(mem, vlm=cfg):
            link = Link()
            s.service.attach(link)
            with s.client() as c:
                r = c.post("/ask", json={"question": "where is the magenta box?"})
                assert r.status_code == 422, r.text
                body = r.json()
                assert body["error"].startswith("unsupported answer: its position is 23.6 m")
                assert body["answer"]["unsupported"] is True and link.answers == []
                r = c.post("/ask", json={"question": "where is the magenta box?", "allow_unsupported": True})
                assert r.status_code == 200 and r.json()["unsupported"] is True
                assert len(link.answers) == 1  # allowed: the robot link gets it
                r = c.post("/ask", json={"question": "where is the magenta box?", "navigate": True})
                assert r.status_code == 400 and "no map" in r.json()["error"]  # this memory has no map
    del mem_path


def test_post_ask_with_navigation_plans_on_the_served_memory(tmp_path):
    from tests.server.conftest import make_memory, serve_memory

    mem = make_memory(tmp_path / "m.mem")
    with_map(mem.path)
    ids = {r.frame_index: r.id for r in mem.all_records()}
    script = [tool("search_time", time="+70"), answer(question_type="position", evidence=[ids[7]])]
    script += invented(ids)
    with ScriptedModel(script) as srv:
        cfg = VLMConfig(base_url=srv.base_url, model="scripted", api_key="k", timeout=5, max_retries=0)
        for s in serve_memory(mem, vlm=cfg):
            with s.client() as c:
                ok = c.post("/ask", json={"question": "where is the magenta box?", "navigate": True})
                bad = c.post("/ask", json={"question": "where is the magenta box?", "navigate": True})
    assert ok.status_code == 200, ok.text
    nav = ok.json()["navigation"]
    assert nav["ok"] and nav["path_length_m"] > 0 and nav["pose_stamped"]["header"]["frame_id"] == "map"
    assert bad.status_code == 422 and bad.json()["answer"]["navigation"]["problem"] == "answer"


def test_mcp_ask_refuses_an_invented_place(tmp_path):
    import anyio
    from mcp import Client

    from tests.server.conftest import make_memory, serve_memory

    mem = make_memory(tmp_path / "m.mem")
    ids = {r.frame_index: r.id for r in mem.all_records()}
    with ScriptedModel(invented(ids) * 2) as srv:
        cfg = VLMConfig(base_url=srv.base_url, model="scripted", api_key="k", timeout=5, max_retries=0)
        for s in serve_memory(mem, vlm=cfg):

            async def main(url: str) -> tuple:
                async with Client(f"{url}/mcp", read_timeout_seconds=60) as client:
                    bad = await client.call_tool("ask", {"question": "where is the magenta box?"})
                    args = {"question": "where is the magenta box?", "allow_unsupported": True}
                    return bad, await client.call_tool("ask", args)

            bad, good = anyio.run(main, s.url)
    assert bad.is_error and bad.content[0].text.startswith("unsupported answer:")
    assert not good.is_error and json.loads(good.content[0].text)["unsupported"] is True


def test_ask_through_a_service_reports_the_refusal_and_exits_1(cli, tmp_path):
    from tests.server.conftest import make_memory, serve_memory

    mem = make_memory(tmp_path / "m.mem")
    ids = {r.frame_index: r.id for r in mem.all_records()}
    with ScriptedModel(invented(ids) * 2) as srv:
        cfg = VLMConfig(base_url=srv.base_url, model="scripted", api_key="k", timeout=5, max_retries=0)
        for s in serve_memory(mem, vlm=cfg):
            r = cli("ask", "Where is the magenta box?", "--server", s.url, "--json")
            allowed = cli(
                "ask", "Where is the magenta box?", "--server", s.url, "--json", "--allow-unsupported"
            )
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert r.stderr.strip().startswith("unsupported answer: its position is 23.6 m")
    assert json.loads(r.stdout)["unsupported"] is True  # the answer is still shown
    assert allowed.returncode == 0, allowed.stderr
    assert json.loads(allowed.stdout)["unsupported"] is True


def test_every_goal_front_end_refuses_an_invented_place_through_the_one_goal_path(tmp_path):
    """MCP `ask` with navigate and `ravenmem_msgs/srv/Ask` with navigate: the answer goes to
    `nav.goals.goal_for`, which refuses the unsupported position (problem `answer`); no goal,
    no drive, and the robot link is not told."""
    import anyio
    from mcp import Client

    from ravenmem.ros.services import ServiceBackend, ask_reply
    from tests.server.conftest import make_memory, serve_memory

    mem = make_memory(tmp_path / "m.mem")
    with_map(mem.path)
    ids = {r.frame_index: r.id for r in mem.all_records()}
    drives: list = []
    with ScriptedModel(invented(ids) * 3) as srv:
        cfg = VLMConfig(base_url=srv.base_url, model="scripted", api_key="k", timeout=5, max_retries=0)
        for s in serve_memory(mem, vlm=cfg):
            link = Link()
            s.service.attach(link)

            async def main(url: str) -> tuple:
                async with Client(f"{url}/mcp", read_timeout_seconds=60) as client:
                    args = {"question": "where is the magenta box?", "navigate": True}
                    bad = await client.call_tool("ask", args)
                    return bad, await client.call_tool("ask", args | {"allow_unsupported": True})

            bad, allowed = anyio.run(main, s.url)
            backend = ServiceBackend(s.service, drive=drives.append)
            reply = ask_reply(backend, {"question": "where is the magenta box?", "navigate": True})
            told = list(link.answers)
    assert bad.is_error and bad.content[0].text.startswith("unsupported answer: its position is 23.6 m")
    nav = json.loads(allowed.content[0].text)["navigation"]
    assert nav["problem"] != "answer"  # allowed: planned (a path, or where no path was found)
    assert reply["unsupported"] is True and reply["goal"] == {} and drives == []
    assert (
        reply["reason"].startswith("unsupported answer: its position is 23.6 m")
        and "stays put" in reply["reason"]
    )
    assert json.loads(reply["answer_json"])["navigation"]["problem"] == "answer"
    assert len(told) == 1  # only the allowed MCP answer reached the robot link
