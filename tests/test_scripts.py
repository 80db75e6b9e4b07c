"""The scripts stand on the package, not on the tests: no script puts tests/ on sys.path or imports a test module
(the standard scenes are varint.scene.standard's; the runs several scripts and tests share are scripts/_runs.py's),
and every script's imports of varint and of its sibling scripts resolve.

Read from the source (ast), so a script is never run here: they are long benchmarks."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted((ROOT / "scripts").rglob("*.py"))
#: the modules a script would import from tests/ (test modules, conftest, helpers)
TEST_MODULES = {p.stem for p in (ROOT / "tests").glob("*.py")}


def _mentions_tests(node, tainted):
    """Whether an expression names the tests folder: a string holding "tests", or a name assigned from one."""
    for n in ast.walk(node):
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and "tests" in n.value:
            return True
        if isinstance(n, ast.Name) and n.id in tainted:
            return True
    return False


def _is_sys_path(node):
    return isinstance(node, ast.Attribute) and node.attr == "path" and isinstance(node.value, ast.Name) \
        and node.value.id == "sys"


def problems(source, name="<script>"):
    """Each place where ``source`` puts tests/ on sys.path or imports a test module, as 'name:line: what'."""
    tree = ast.parse(source)
    out = []
    # names bound to a path of the tests folder (ROOT / "tests", then sys.path.insert(0, str(that)))
    tainted = set()
    changed = True
    while changed:
        changed = False
        for n in ast.walk(tree):
            if isinstance(n, (ast.Assign, ast.AnnAssign, ast.AugAssign)) and n.value is not None \
                    and _mentions_tests(n.value, tainted):
                targets = n.targets if isinstance(n, ast.Assign) else [n.target]
                for t in targets:
                    for m in ast.walk(t):
                        if isinstance(m, ast.Name) and m.id not in tainted:
                            tainted.add(m.id)
                            changed = True
    for n in ast.walk(tree):
        if isinstance(n, ast.stmt) and not isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.If,
                                                           ast.For, ast.While, ast.With, ast.Try)):
            if any(_is_sys_path(m) for m in ast.walk(n)) and _mentions_tests(n, tainted):
                out.append(f"{name}:{n.lineno}: puts tests/ on sys.path")
        if isinstance(n, ast.Import):
            for a in n.names:
                if a.name.split(".")[0] in TEST_MODULES:
                    out.append(f"{name}:{n.lineno}: imports the test module {a.name}")
        elif isinstance(n, ast.ImportFrom) and not n.level and n.module \
                and n.module.split(".")[0] in TEST_MODULES:
            out.append(f"{name}:{n.lineno}: imports from the test module {n.module}")
    return out


def test_no_script_puts_tests_on_sys_path_or_imports_a_test_module():
    bad = [p for f in SCRIPTS for p in problems(f.read_text(encoding="utf-8"), str(f.relative_to(ROOT)))]
    assert not bad, "scripts that lean on tests/:\n" + "\n".join(bad)


@pytest.mark.parametrize("source, what", [
    ('import sys\nfrom pathlib import Path\nROOT = Path(__file__).parent.parent\nsys.path.insert(0, str(ROOT / "tests"))\n',
     "sys.path"),
    ('import os, sys\nsys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))\n', "sys.path"),
    ('import sys\nfrom pathlib import Path\np = Path("x") / "tests"\nq = str(p)\nsys.path.append(q)\n', "sys.path"),
    ("from test_rod import rod_scene\n", "test module"),
    ("def f():\n    import test_flowing_pipe as T\n", "test module"),
    ("from helpers import make\n", "test module"),
])
def test_the_rule_catches_what_it_is_for(source, what):
    """Each way a script leaned on tests/ before varint.scene.standard (the rule is not vacuous)."""
    found = problems(source)
    assert found and all(what in p for p in found), found


def _imports_of(path):
    """The script's import statements of varint and of sibling scripts (at any depth), as source lines."""
    siblings = {p.stem for p in SCRIPTS}
    out = []
    for n in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(n, ast.Import):
            names = [a for a in n.names if a.name.split(".")[0] == "varint" or a.name in siblings]
            if names:
                out.append(ast.unparse(ast.Import(names=names)))
        elif isinstance(n, ast.ImportFrom) and not n.level and n.module \
                and (n.module.split(".")[0] == "varint" or n.module in siblings):
            out.append(ast.unparse(n))
    return out


def test_every_script_s_imports_resolve():
    """The package's layout moves; the scripts must follow it.  Their varint and sibling imports run in one
    interpreter with scripts/ on sys.path (the scripts themselves are not run)."""
    stmts = sorted({s for f in SCRIPTS for s in _imports_of(f)})
    code = ("import sys\nsys.path[:0] = [%r]\nbad = []\nfor s in %r:\n    try:\n        exec(s, {})\n"
            "    except Exception as exc:\n        bad.append(f'{s}: {exc.__class__.__name__}: {exc}')\n"
            "print('\\n'.join(bad))\nsys.exit(1 if bad else 0)\n") % (str(ROOT / "scripts"), stmts)
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
