"""Scene text as data: dotted key paths resolved against the schema, set in a parsed TOML document, and the
document written back as TOML.  ``varint sweep`` varies keys this way; the standard scenes
(:mod:`varint.scene.standard`) and the tests write their scenes with :func:`to_toml`.
"""

from __future__ import annotations

import difflib
import json
import math
import re

import numpy as np

from ..errors import VarintError
from .schema import REQUIRED, SCHEMA

__all__ = ["KeyPathError", "resolve_key", "set_key", "to_toml"]


class KeyPathError(VarintError):
    """A dotted key that names no scene key, or a document the key cannot be set in."""


_SEGMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")


def _all_keys():
    out = []
    for sec, keys in SCHEMA.items():
        prefix = sec.replace("[]", "[0]")
        out += [f"{prefix}.{k.name}" if prefix else k.name for k in keys]
    return out


def resolve_key(key):
    """``"fluid.perturbation[0].amplitude"`` -> (path, Key declaration); raises ``KeyPathError``.

    Tables are dotted; an array of tables takes an index (``[0]``); a vector key (kind ``vec3``)
    takes the index of its component.
    """
    where = f"--vary {key}"
    parts = key.split(".")
    path = []
    for p in parts:
        m = _SEGMENT.match(p)
        if not m:
            raise KeyPathError(f"{where}: not a dotted scene key (like rod.initial.angular_velocity[0] or time.step)")
        path.append((m.group(1), None if m.group(2) is None else int(m.group(2))))
    table = ".".join(n + ("[]" if i is not None else "") for n, i in path[:-1])
    leaf, index = path[-1]
    decl = None
    if table in SCHEMA:
        decl = next((k for k in SCHEMA[table] if k.name == leaf), None)
    if decl is None:
        bare = re.sub(r"\[\d+\]", "[0]", key)
        near = difflib.get_close_matches(bare, _all_keys(), n=1, cutoff=0.6)
        hint = f" (did you mean '{near[0]}'?)" if near else ""
        arrays = [n[:-2] for n in SCHEMA if n.endswith("[]")]
        for n in arrays:  # an array of tables written without its index
            if (table + ".").startswith(n + ".") and f"{n}[]" not in table:
                hint = f" ({n} is an array of tables: index it, e.g. {n}[0].{key[len(n) + 1:]})"
        raise KeyPathError(f"{where}: unknown scene key{hint}")
    if decl.kind == "vec3":
        if index is None:
            raise KeyPathError(f"{where}: is a vector; vary one component, e.g. {key}[0]")
        if index > 2:
            raise KeyPathError(f"{where}: a vector has components [0], [1], [2]")
    elif index is not None:
        raise KeyPathError(f"{where}: is a single value ({decl.kind}), not a vector: remove [{index}]")
    elif decl.kind not in ("float", "int", "str"):
        raise KeyPathError(f"{where}: a {decl.kind} key cannot be varied")
    return path, decl


def set_key(doc, path, value):
    """Set ``path`` (from :func:`resolve_key`) in the TOML document ``doc`` (a dict, changed in place).

    Missing tables are created; an array-of-tables entry must exist; a vector component starts from
    the key's default when the vector is absent.  Raises ``KeyPathError``.
    """
    node = doc
    shown = []
    for name, index in path[:-1]:
        shown.append(name)
        if index is None:
            child = node.setdefault(name, {})
            if not isinstance(child, dict):
                raise KeyPathError(f"{'.'.join(shown)}: is not a table in the scene")
            node = child
        else:
            arr = node.get(name)
            if not isinstance(arr, list) or index >= len(arr):
                have = len(arr) if isinstance(arr, list) else 0
                raise KeyPathError(f"{'.'.join(shown)}[{index}]: the scene has {have} [[{'.'.join(shown)}]] "
                                 f"table{'s' if have != 1 else ''}")
            node = arr[index]
            shown[-1] += f"[{index}]"
    name, index = path[-1]
    if index is None:
        node[name] = value
        return doc
    vec = node.get(name)
    if vec is None:
        table = ".".join(n + ("[]" if i is not None else "") for n, i in path[:-1])
        decl = next(k for k in SCHEMA[table] if k.name == name)
        vec = list(decl.default) if decl.default not in (None, REQUIRED) else [0.0, 0.0, 0.0]
    if not isinstance(vec, list) or index >= len(vec):
        raise KeyPathError(f"{'.'.join(shown + [name])}: is not a vector with a component [{index}] in the scene")
    vec = list(vec)
    vec[index] = value
    node[name] = vec
    return doc


_BARE = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(k):
    return k if _BARE.match(k) else json.dumps(k, ensure_ascii=False)


def _value(v):
    if isinstance(v, np.generic):  # numpy scalars, as scene dicts built in Python hold them
        v = v.item()
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a JSON string is a TOML basic string
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")  # dates: no scene key has one


def _is_table_array(v):
    return isinstance(v, list) and v and all(isinstance(x, dict) for x in v)


def _table(lines, prefix, d):
    for k, v in d.items():
        if not isinstance(v, dict) and not _is_table_array(v):
            lines.append(f"{_key(k)} = {_value(v)}")
    for k, v in d.items():
        name = f"{prefix}.{_key(k)}" if prefix else _key(k)
        if isinstance(v, dict):
            lines.append(f"\n[{name}]")
            _table(lines, name, v)
        elif _is_table_array(v):
            for item in v:
                lines.append(f"\n[[{name}]]")
                _table(lines, name, item)


def to_toml(doc):
    """A TOML document (as ``tomllib.loads`` returns it) as text; ``tomllib.loads(to_toml(d)) == d``.

    Tables become ``[sections]`` (inline tables too), arrays of tables ``[[sections]]``, at any depth.
    Comments of the original are not kept.
    """
    lines = []
    _table(lines, "", doc)
    return "\n".join(lines).lstrip("\n") + "\n"
