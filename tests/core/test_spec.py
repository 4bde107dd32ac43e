"""The one KEY=VALUE spec parser (`ravenmem.spec`) and the options that use it: each keeps the
words of its own errors, and the rules (blank parts skipped, a known key, never twice) are the
same for all."""

from __future__ import annotations

import pytest

from ravenmem.agent.presets import parse_top_k
from ravenmem.embed.offline import parse_spec
from ravenmem.errors import InputError
from ravenmem.eval.config import parse_pos_threshold
from ravenmem.ingest.keyframes import KeyframeConfig
from ravenmem.ros.link import LinkConfig
from ravenmem.spec import pairs, split_pair


def test_the_rules():
    assert pairs(" a=1, ,b = x ", "--opt") == {"a": "1", "b": "x"}
    assert pairs(["a=1", "a=2"], "--opt", repeat=True) == {"a": "2"}
    assert split_pair("k=") is None and split_pair("k=", empty_value=True) == ("k", "")
    assert split_pair("=v") is None and split_pair("novalue") is None
    for spec, words in (
        ("a=1,a=2", "--opt: a is given twice"),
        ("c=1", "--opt: unknown key 'c'; choose from a, b"),
        ("a", "--opt: 'a' is not key=value (keys: a, b)"),
        ("a=", "--opt: 'a=' is not key=value"),
    ):
        with pytest.raises(InputError) as e:
            pairs(spec, "--opt", known=["a", "b"])
        assert str(e.value).startswith(words), str(e.value)


@pytest.mark.parametrize(
    ("parse", "spec", "words"),
    [
        (KeyframeConfig.from_spec, "fps=2,fps=3", "keyframes: fps is given twice"),
        (KeyframeConfig.from_spec, "speed=2", "keyframes: unknown key 'speed'; choose from stride"),
        (KeyframeConfig.from_spec, "fps", "keyframes: 'fps' is not key=value (keys: stride"),
        (KeyframeConfig.from_spec, "fps=", "keyframes: fps='' is not a number"),
        (LinkConfig.from_spec, "image=cam,image=x,pose=odom", "zenoh: image is given twice"),
        (LinkConfig.from_spec, "image=cam,pose", "zenoh: 'pose' is not key=value"),
        (LinkConfig.from_spec, "image=cam,pose=odom,colour=1", "zenoh: unknown key 'colour'"),
        (parse_top_k, "text=lots", "--top-k: expected N or tool=N,... with whole numbers"),
        (parse_top_k, "text", "--top-k: expected N or tool=N"),
        (parse_pos_threshold, "real_world", "--pos-threshold: expected numbers"),
        (parse_pos_threshold, "real_world=3,=2", "--pos-threshold: expected subset=metres, got '=2'"),
        (parse_spec, "offline:colour=3", "offline embedder spec"),
    ],
)
def test_every_spec_option_keeps_its_words(parse, spec, words):
    with pytest.raises(InputError) as e:
        parse(spec)
    assert str(e.value).startswith(words) and "\n" not in str(e.value), str(e.value)


def test_every_spec_option_parses_through_it():
    assert KeyframeConfig.from_spec("default,fps=2").fps == 2.0
    assert parse_top_k("text=30, time=200,") == {"text": 30, "time": 200}
    assert parse_pos_threshold("real_world=3,habitat_sim=1") == {"real_world": 3.0, "habitat_sim": 1.0}
    assert LinkConfig.from_spec("image=cam, pose=odom,").image == "cam"
