"""Scene files: TOML loading, --set overrides by dotted key, validation, dispatch.

Validation leaves what it is given as it was and returns a CheckedScene: the tables,
read-only, with every default filled in, and what the script module's check derived
from them (the bodies, the Lame coefficients, ...) as attributes.

A scene names the FreeFEM script that solves it (scene.script); each script has
a module here with its schema and its mapping to FreeFEM command-line flags.
"""

import copy
import importlib
import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from .errors import SceneError
from .header import LIMITS, SCENE_HEADER, check_units
from .schema import validate


class ReadOnly:
    """What a checked scene's tables and arrays share: changes refused, copies are the
    object itself (nothing can change it), pickled as the plain value."""

    def refuse(self, *args, **kwargs):
        raise TypeError("a checked scene is read-only (fdcontact.Scene.set makes a changed scene)")

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self

    def __reduce__(self):
        return type(self), (self.plain(self),)


class FrozenTable(ReadOnly, dict):
    """A table of a checked scene: a dict that refuses changes (so that it still reads,
    prints and serializes as one)."""

    plain = dict
    __setitem__ = __delitem__ = __ior__ = clear = pop = popitem = setdefault = update = ReadOnly.refuse


class FrozenList(ReadOnly, list):
    """An array of a checked scene: a list that refuses changes."""

    plain = list
    __setitem__ = __delitem__ = __iadd__ = __imul__ = append = clear = extend = insert = pop = remove = \
        reverse = sort = ReadOnly.refuse


def frozen(value):
    """A read-only copy of nested tables and arrays."""
    if isinstance(value, dict):
        return FrozenTable({k: frozen(v) for k, v in value.items()})
    if isinstance(value, list):
        return FrozenList(frozen(v) for v in value)
    return value


def thawed(value):
    """A plain, changeable copy of nested tables and arrays."""
    if isinstance(value, dict):
        return {k: thawed(v) for k, v in value.items()}
    if isinstance(value, list):
        return [thawed(v) for v in value]
    return value


@dataclass(frozen=True, eq=False)
class CheckedScene(Mapping):
    """A validated scene, read-only: its tables with every default filled in (read as a
    mapping: scene["mesh"]["nx"]), and what validation derived from them as attributes.

    source: how errors name the scene; base_dir: the folder the files it names are read
    from; module: its script's module (driver/fd2d.py, fd3d.py, foundation.py). Two-body
    scripts: bodies (driver/scene_module.Bodies: shapes, supports, loads, probes) and lame
    (each body's (lambda, mu)). Foundation: young_nu ((E, nu)), geo_path (a gmsh scene's
    .geo file) and label_ids (each boundary's label as the mesh's id)."""

    tables: FrozenTable
    module: ModuleType
    source: str
    base_dir: Path
    bodies: object = None
    lame: tuple = ()
    young_nu: tuple = ()
    geo_path: Path = None
    label_ids: tuple = ()

    def __getitem__(self, key):
        return self.tables[key]

    def __iter__(self):
        return iter(self.tables)

    def __len__(self):
        return len(self.tables)

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self

    def to_dict(self):
        """The tables as plain dicts and lists (what scene.json holds)."""
        return thawed(self.tables)


def full_schema(module):
    """Every table a scene of this script module may hold."""
    return dict(scene=SCENE_HEADER, **module.SCHEMA, limits=LIMITS)


# Each script's module (driver/NAME.py), imported when a scene names the script (and here,
# not at the top, so that each script module can import this one).
SCRIPT_MODULES = {"contact_foundation_2d": "foundation", "fd_contact_2d": "fd2d", "fd_contact_3d": "fd3d"}


def script_module(script):
    return importlib.import_module(f".{SCRIPT_MODULES[script]}", __package__)


def script_modules():
    return {script: script_module(script) for script in SCRIPT_MODULES}


def parse_override(text):
    """'a.b=value' -> (['a', 'b'], value) with value read as a TOML literal."""
    if "=" not in text:
        raise SceneError(f"override '{text}': expected KEY=VALUE")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key:
        raise SceneError(f"override '{text}': empty key")
    try:
        value = parse_toml(f"v = {raw.strip()}", f"override '{text}'")["v"]
    except SceneError as exc:
        if "nested" in str(exc):
            raise
        value = raw.strip()          # bare words are strings: method.stabilization=ghost
    return key.split("."), value


def apply_override(data, path, value, source):
    node = data
    for i, part in enumerate(path[:-1]):
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise SceneError(f"{source}: override '{'.'.join(path)}': no item {part}")
            node = node[int(part)]
            continue
        node = node.setdefault(part, {})
        if not isinstance(node, (dict, list)):
            raise SceneError(f"{source}: override '{'.'.join(path)}': '{part}' is not a table")
    last = path[-1]
    if isinstance(node, list):
        if not last.isdigit() or int(last) >= len(node):
            raise SceneError(f"{source}: override '{'.'.join(path)}': no item {last}")
        node[int(last)] = value
    else:
        node[last] = value


def read_text_file(path, what):
    """The UTF-8 text of a scene or sweep file, or one SceneError naming why not."""
    try:
        if path.is_dir():
            raise SceneError(f"{path}: is a folder, not a {what}")
        data = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"{path}: cannot read {what} ({exc.strerror})") from None
    if b"\0" in data:
        raise SceneError(f"{path}: not a text file (binary data); a {what} is TOML text")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not UTF-8 text (byte {exc.start}); a {what} is TOML text") from None


MAX_TOML_DEPTH = 40


def parse_toml(text, source):
    """The tables of a TOML text, or one SceneError: malformed, or nested deeper than a scene needs
    (checked before parsing: the TOML reader recurses once per level)."""
    depth = deepest = 0
    quote = comment = escaped = None
    for char in text:
        if comment:
            comment = char != "\n"
        elif quote:
            if escaped:
                escaped = False
            elif char == "\\" and quote == '"':
                escaped = True
            elif char == quote:
                quote = None
        elif char == "#":
            comment = True
        elif char in "\"'":
            quote = char
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    if deepest > MAX_TOML_DEPTH:
        raise SceneError(f"{source}: arrays or tables nested {deepest} deep; at most {MAX_TOML_DEPTH}")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{source}: malformed TOML: {exc}") from None
    except RecursionError:
        raise SceneError(f"{source}: arrays or tables nested too deep") from None


def load_scene(path, overrides=()):
    """Read, override and validate a scene file; return (CheckedScene, script module)."""
    path = Path(path)
    source = str(path)
    data = parse_toml(read_text_file(path, "scene file"), source)
    return load_scene_data(data, source, path.parent, overrides)


def load_scene_data(data, source, base_dir, overrides=()):
    """Override and validate a scene given as tables (source: how errors name it; base_dir:
    the folder its files, e.g. a gmsh shape's, are read from); (CheckedScene, script module).
    `data` is left as it was."""
    if not isinstance(data, dict):
        raise SceneError(f"{source}: a scene is a table of tables, got {type(data).__name__}")
    data = copy.deepcopy(data)
    for text_override in overrides:
        keys, value = parse_override(text_override)
        apply_override(data, keys, value, source)
    header = validate(data.get("scene", {}), SCENE_HEADER, source, "scene.")
    check_units(header["units"], source)
    if header["script"] not in SCRIPT_MODULES:
        known = ", ".join(sorted(SCRIPT_MODULES))
        raise SceneError(f"{source}: key 'scene.script': unknown script {header['script']!r} (known: {known})")
    module = script_module(header["script"])
    base_dir = Path(base_dir)
    tables, derived = module.check(validate(data, full_schema(module), source), source, base_dir)
    return CheckedScene(frozen(tables), module, source, base_dir, **derived), module


def toml_literal(value):
    """A value as a TOML literal that reads back to the same value (tables inline)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_literal(v) for v in value) + "]"
    if isinstance(value, dict):      # an inline table: a shape, a hold, a load
        return "{ " + ", ".join(f"{json.dumps(k)} = {toml_literal(v)}" for k, v in value.items()) + " }"
    raise SceneError(f"value {value!r}: not a TOML value")


def toml_text(data):
    """A scene's tables as TOML text: each top-level table a [section] of key = literal lines
    (nested tables and arrays of tables inline)."""
    lines = [f"{json.dumps(key)} = {toml_literal(value)}" for key, value in data.items()
             if not isinstance(value, dict)]          # top-level values ([[probe]]) before any table
    for section, table in data.items():
        if isinstance(table, dict):
            lines.append(f"\n[{json.dumps(section)}]")
            lines += [f"{json.dumps(key)} = {toml_literal(value)}" for key, value in table.items()]
    return "\n".join(lines).lstrip() + "\n"
