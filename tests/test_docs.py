"""Generated documentation is current."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_scene_docs_match_schema():
    spec = importlib.util.spec_from_file_location("wsd", ROOT / "scripts" / "write_scene_docs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert (ROOT / "docs" / "scenes.md").read_text() == mod.render(), "run scripts/write_scene_docs.py"


def test_project_cites_only_what_users_have():
    """Docs, code and scripts cite the paper, the literature and files in this repository, never the
    maintainers' internal notes (files that are not shipped)."""
    internal = ("DESIGN.md", "DESIGN §", "ANCHORS", "shared/")
    paths = [ROOT / "README.md", ROOT / "CITATION.cff"]
    for folder, pattern in (("varint", "*.py"), ("scripts", "*.py"), ("docs", "*.md"), ("tests", "*.py"), ("examples", "*.toml")):
        paths += sorted((ROOT / folder).glob(pattern))
    this = Path(__file__).resolve()
    bad = [f"{p.relative_to(ROOT)}: {word}" for p in paths if p.resolve() != this
           for word in internal if word in p.read_text(encoding="utf-8")]
    assert not bad, bad
