"""The Search service carries the text tool's verdict (ravenmem.agent.support) in each
`ravenmem_msgs/Memory`, through the real CDR encoding of the shipped interface files."""

from __future__ import annotations

from pathlib import Path

import ravenmem
from ravenmem.ros import msgs
from ravenmem.ros.services import ServiceBackend, register, search_reply
from ravenmem.runtime.service import Service, ServiceConfig
from tests.conftest import ColorEmbedder

RESPONSE = "ravenmem_msgs/srv/Search_Response"


def test_search_replies_say_which_memories_support_the_query(mem_path: Path) -> None:
    register()
    service = Service(ravenmem.open(mem_path, embedder=ColorEmbedder()), ServiceConfig()).start()
    try:
        backend = ServiceBackend(service)
        replies = {
            q: msgs.deserialize(
                msgs.serialize(msgs.to_message(search_reply(backend, req), RESPONSE), RESPONSE), RESPONSE
            )
            for q, req in {
                "red": {"tool": "text", "query": "red", "k": 2},
                "toast": {"tool": "text", "query": "a smell of toast", "k": 3},
                "time": {"tool": "time", "query": "+20s", "k": 2},
            }.items()
        }
    finally:
        service.close()
    assert all(r.error == "" for r in replies.values())
    assert [m.supported for m in replies["red"].memories] == [True, True]
    assert [m.supported for m in replies["toast"].memories] == [False, False, False]
    assert [m.supported for m in replies["time"].memories] == [True, True]  # not judged
