"""Generated documentation is current."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_scene_docs_match_schema():
    spec = importlib.util.spec_from_file_location("wsd", ROOT / "scripts" / "write_scene_docs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert (ROOT / "docs" / "scenes.md").read_text() == mod.render(), "run scripts/write_scene_docs.py"
