"""The one way backends load: built-ins lazily by module, third-party ones by entry point."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ravenmem.errors import InputError
from ravenmem.registry import Registry

REPO = Path(__file__).resolve().parents[2]


def test_unknown_name_lists_the_known_ones():
    reg: Registry[object] = Registry("widget", builtins={"a": "json"})
    with pytest.raises(InputError, match=r"unknown widget 'zz'; choose one of: a"):
        reg.create("zz")


def test_naming_one_backend_imports_only_that_one():
    code = textwrap.dedent(
        """
        import sys
        from ravenmem.store.base import STORES
        assert "milvus" in STORES.names() and "ravenmem.store.milvus" not in sys.modules
        STORES.get("local")
        assert "ravenmem.store.local" in sys.modules and "ravenmem.store.milvus" not in sys.modules
        print("ok")
        """
    )
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": str(REPO / "src")}
    )
    assert r.stdout.strip() == "ok", r.stderr


def test_every_registry_loads_its_builtins_lazily():
    """Datasets too: naming one imports its loader's module only (and every name is listed)."""
    code = textwrap.dedent(
        """
        import sys
        from ravenmem.eval.datasets import DATASETS
        loaded = lambda: sorted(m.rsplit(".", 1)[1] for m in sys.modules if m.startswith("ravenmem.eval.datasets."))
        names = DATASETS.names()
        assert {"raven-qa", "navqa", "findingdory", "tum", "memory", "queries"} <= set(names), names
        assert loaded() == [], loaded()
        DATASETS.get("navqa")
        assert "navqa" in loaded() and not {"ravenqa", "findingdory", "generic"} & set(loaded()), loaded()
        DATASETS.get("tum")
        assert "generic" in loaded() and "ravenqa" not in loaded(), loaded()
        print("ok")
        """
    )
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": str(REPO / "src")}
    )
    assert r.stdout.strip() == "ok", r.stderr


def test_third_party_backend_through_an_entry_point(tmp_path: Path):
    pkg = tmp_path / "site"
    (pkg / "thirdparty_emb.py").parent.mkdir(parents=True)
    (pkg / "thirdparty_emb.py").write_text(
        "def make(spec, **kw):\n    return ('made', spec)\n", encoding="utf-8"
    )
    dist = pkg / "thirdparty_emb-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdparty-emb\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[ravenmem.embedders]\nmine = thirdparty_emb:make\n")
    code = textwrap.dedent(
        """
        from ravenmem.embed.base import EMBEDDERS
        assert "mine" in EMBEDDERS.names(), EMBEDDERS.names()
        print(EMBEDDERS.create("mine:opts"))
        """
    )
    env = {"PYTHONPATH": f"{REPO / 'src'}:{pkg}"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert r.stdout.strip() == "('made', 'opts')", r.stderr
