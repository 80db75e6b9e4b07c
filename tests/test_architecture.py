"""The package's layers (docs/architecture.md): dependencies point one way, no module imports a private name from
another package, and no import cycle exists, counting the imports inside functions.

The graph is read from the source (every ``import`` and ``from ... import`` statement, at module level and inside
functions), so a cycle hidden behind a function-level import fails here as an upward arrow."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent / "varint"

#: each top-level package or module of varint and its layer: a module may import from lower layers and from its own
#: package only (docs/architecture.md draws this)
LAYERS = {
    "errors": 0, "version": 0,
    "lattice": 1, "exact": 1,
    "scene": 2,
    "terms": 3,
    "model": 4,
    "schemes": 5,
    "run": 6,
    "analysis": 7,
    "plotting": 8, "sweep": 8, "capabilities": 8,
    "cli": 9,
    "__init__": 10, "__main__": 10,
}


def _modules():
    """{dotted name: path} of every module of the package."""
    out = {}
    for p in sorted(ROOT.rglob("*.py")):
        parts = list(p.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__" and len(parts) > 1:
            parts = parts[:-1]
            name = ".".join(parts)
            out[name] = p
            out[name + ".__init__"] = p  # (resolution of relative imports needs the package flag below)
        else:
            out[".".join(parts)] = p
    return {k: v for k, v in out.items() if not k.endswith(".__init__")}


MODULES = _modules()


def _is_package(name):
    return MODULES[name].name == "__init__.py"


def _imports(name):
    """[(imported module, [names], line)] of module ``name``: every import statement, at any depth."""
    path = MODULES[name]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    pkg = name if _is_package(name) else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod == "varint" or mod.startswith("varint."):
                names = [a.name for a in node.names]
                # "from varint.x import y" where y is a module: the import is of varint.x.y
                subs = [n for n in names if f"{mod}.{n}" in MODULES]
                for n in subs:
                    out.append((f"{mod}.{n}", [], node.lineno))
                rest = [n for n in names if n not in subs]
                if rest or not subs:
                    out.append((mod, rest, node.lineno))
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name == "varint" or a.name.startswith("varint."):
                    out.append((a.name, [], node.lineno))
    return out


def _top(name):
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _package(name):
    """The package a module belongs to, for the private-name rule: 'varint.terms' for varint.terms.rod."""
    return name if _is_package(name) else name.rpartition(".")[0]


def test_every_module_has_a_layer():
    assert {_top(m) for m in MODULES} <= set(LAYERS), sorted({_top(m) for m in MODULES} - set(LAYERS))


def test_dependencies_point_down_the_layers():
    bad = []
    for name in MODULES:
        here = _top(name)
        for mod, _, line in _imports(name):
            there = _top(mod)
            if there == here:
                continue
            if LAYERS[there] >= LAYERS[here]:
                bad.append(f"{name}:{line} imports {mod} "
                           f"(layer {LAYERS[here]} {here} -> layer {LAYERS[there]} {there})")
    assert not bad, "upward or sideways imports:\n" + "\n".join(bad)


def test_no_private_name_is_imported_across_packages():
    bad = []
    for name in MODULES:
        for mod, names, line in _imports(name):
            if mod not in MODULES or _package(mod) == _package(name):
                continue
            for n in names:
                if n.startswith("_") and not n.startswith("__"):
                    bad.append(f"{name}:{line} imports {mod}.{n}")
    assert not bad, "private names imported across packages:\n" + "\n".join(bad)


def test_no_import_cycle():
    graph = {name: {mod for mod, _, _ in _imports(name) if mod in MODULES and mod != name} for name in MODULES}
    # a package's __init__ re-exports: an import of a package counts as an import of its __init__ only
    seen, stack, cycles = set(), [], []

    def visit(n, on_path):
        if n in on_path:
            cycles.append(stack[stack.index(n):] + [n])
            return
        if n in seen:
            return
        seen.add(n)
        on_path.add(n)
        stack.append(n)
        for m in sorted(graph[n]):
            visit(m, on_path)
        stack.pop()
        on_path.discard(n)

    for n in sorted(graph):
        visit(n, set())
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


#: what the package outside varint.schemes may import of it: the registry (which scheme steps a model), the protocol and
#: the state they exchange; an engine chosen anywhere else would be a second way to step a model
SCHEME_FRONT = {"varint.schemes.registry", "varint.schemes.base", "varint.schemes.state"}


def test_no_engine_is_chosen_outside_the_registry():
    bad = []
    for name in MODULES:
        if _top(name) == "schemes":
            continue
        for mod, _, line in _imports(name):
            if _top(mod) == "schemes" and mod not in SCHEME_FRONT:
                bad.append(f"{name}:{line} imports {mod}")
    assert not bad, "engines imported outside varint.schemes (use varint.schemes.registry):\n" + "\n".join(bad)


@pytest.mark.parametrize("broken", ["upward", "private", "cycle", "engine"])
def test_the_rules_catch_what_they_are_for(broken, monkeypatch, tmp_path):
    """Each rule fails on a module written to break it (the rules are not vacuous)."""
    import varint  # noqa: F401

    fake = tmp_path / "fake.py"
    src = {"upward": "from ..run.simulation import Simulation\n",
           "private": "from ..terms.rod import _T\n",
           "cycle": "from ..lattice import lie\n",
           "engine": "from ..schemes.em_rod import RodEMStep\n"}[broken]
    fake.write_text(src)
    name = {"upward": "varint.lattice.fake", "private": "varint.schemes.fake", "cycle": "varint.lattice.fake",
            "engine": "varint.run.fake"}[broken]
    monkeypatch.setitem(MODULES, name, fake)
    if broken == "cycle":
        # lie imports the fake module back: lie -> fake -> lie
        lie_src = MODULES["varint.lattice.lie"].read_text() + "\nfrom . import fake\n"
        lie = tmp_path / "lie.py"
        lie.write_text(lie_src)
        monkeypatch.setitem(MODULES, "varint.lattice.lie", lie)
        with pytest.raises(AssertionError, match="cycles"):
            test_no_import_cycle()
    elif broken == "engine":
        with pytest.raises(AssertionError, match="engines imported outside"):
            test_no_engine_is_chosen_outside_the_registry()
    elif broken == "upward":
        with pytest.raises(AssertionError, match="upward"):
            test_dependencies_point_down_the_layers()
    else:
        with pytest.raises(AssertionError, match="private"):
            test_no_private_name_is_imported_across_packages()
