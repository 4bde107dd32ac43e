"""The offline reasoner and the agent's tools on real TUM frames with the offline embedder (slow)."""

from __future__ import annotations

import pytest

import ravenmem
from ravenmem.agent import Agent, OfflineReasoner
from tests.agent.conftest import config_for
from tests.agent.scripted_server import answer, tool

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def tum_mem(tmp_path_factory):
    from tests.conftest import tum_data

    TUM = tum_data()
    from ravenmem.ingest.keyframes import KeyframeConfig
    from ravenmem.ingest.pipeline import ingest
    from ravenmem.ingest.tum import TumSource

    m = ravenmem.create(tmp_path_factory.mktemp("tum") / "tum.mem", embedder="offline", ocr=False)
    ingest(TumSource(TUM, depth=False), m, keyframes=KeyframeConfig.only(stride=12), progress=False)
    yield m
    m.close()


def test_offline_reasoner_on_real_frames(tum_mem):
    r = OfflineReasoner(tum_mem)
    kb = r.ask("Did I see a computer keyboard?")
    assert kb.found and kb.yes is True and kb.evidence
    assert r.ask("Did I see a dog?").yes is False
    last = r.ask("When did I last see the keyboard?")
    t0, t1 = tum_mem.time_span()
    assert last.time is not None and last.time > t1 - 3.0  # the keyboard is in view at the end


def test_agent_tools_on_real_frames(tum_mem, server):
    server.push(
        tool("search_text", query="a computer keyboard"), answer(question_type="position", answer="desk")
    )
    ans = Agent(tum_mem, vlm=config_for(server)).ask("Where is the keyboard?")
    assert not ans.failed and ans.position_source == "evidence" and server.images(1) == 5
    assert ans.cost.memories_total == tum_mem.count() and ans.cost.alpha == pytest.approx(5 / tum_mem.count())
