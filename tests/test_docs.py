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


def _sphinx(src, out):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(src), str(out)],
                          capture_output=True, text=True, timeout=300)


def test_the_documentation_build_fails_on_a_broken_reference(tmp_path):
    """The site's configuration (docs/conf.py), as .ci/run builds it (warnings as errors), on a two-page site: it
    builds, and a link to a missing page, a missing section or a missing API object fails the build."""
    import pytest

    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    src = tmp_path / "docs"
    src.mkdir()
    (src / "conf.py").write_text((ROOT / "docs" / "conf.py").read_text())
    (src / "index.md").write_text("# Home\n\n```{toctree}\nother\n```\n\nSee [the other page](other.md#a-section).\n")
    (src / "other.md").write_text("# Other\n\n## A section\n\n```{eval-rst}\n.. autofunction:: varint.run.xdmf.write_xdmf\n```\n")
    good = _sphinx(src, tmp_path / "html")
    assert good.returncode == 0, good.stderr
    for broken in ("[gone](missing.md)", "[gone](other.md#no-such-section)", "{py:func}`varint.no_such_function`"):
        (src / "index.md").write_text(f"# Home\n\n```{{toctree}}\nother\n```\n\nSee {broken}.\n")
        bad = _sphinx(src, tmp_path / "html")
        assert bad.returncode != 0 and "WARNING" in bad.stderr, broken
