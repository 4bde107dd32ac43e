import pytest

from ravenmem.sim.base import SceneObject
from ravenmem.sim.queries import make_queries, match_kind, phrase_for

OBJS = [
    SceneObject(1, "ExplosiveBarrel", 0.0, 0.0),
    SceneObject(2, "ExplosiveBarrel", 10.0, 0.0),
    SceneObject(3, "GreenArmor", 5.0, 5.0),
    SceneObject(4, "DeadMarine", 1.0, 1.0),
    SceneObject(5, "WeirdThingXL", 2.0, 2.0),
    SceneObject(6, "Chainsaw", 9.0, 9.0),
]


def test_phrases() -> None:
    assert phrase_for("GreenArmor") == "green armor vest"
    assert phrase_for("ExplosiveBarrel") == "explosive barrel"
    assert phrase_for("WeirdThingXL") == "weird thing xl"


def test_queries_only_for_seen_kinds_preferred_first_no_gore() -> None:
    qs = make_queries(OBJS, seen={2, 3, 4, 5})
    assert [q.kind for q in qs] == ["ExplosiveBarrel", "GreenArmor", "WeirdThingXL"]
    barrel = qs[0]
    assert barrel.question == "Where did you see the explosive barrel?"
    assert len(barrel.instances) == 2  # every instance counts for scoring, seen or not
    assert barrel.nearest(9.0, 0.0) == pytest.approx(1.0)
    assert len(make_queries(OBJS, None, max_queries=2)) == 2
    assert [q.kind for q in make_queries(OBJS, None, kinds=["Chainsaw", "Nope"])] == ["Chainsaw"]


def test_match_kind() -> None:
    kinds = [o.kind for o in OBJS]
    assert match_kind("explosive barrel", kinds) == "ExplosiveBarrel"
    assert match_kind("Where is the green armor vest?", kinds) == "GreenArmor"
    assert match_kind("chainsaw", kinds) == "Chainsaw"
    assert match_kind("a red sofa", kinds) is None
