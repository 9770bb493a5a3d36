"""gmsh input as data: the .geo and .msh files a scene names, read without running them.

gmsh's .geo language is a program: it can run commands (SystemCall), read other
files (Include, Merge, MergeWithBoundingBox) and gmsh also reads a sidecar
`NAME.geo.opt` and the user's option files. A scene's .geo is therefore never handed
to gmsh as it is. It is read here by an allow-list of geometry statements (points,
lines, circle and ellipse arcs, splines, curve loops, surfaces, physical groups, mesh
sizes, numeric variables), its expressions evaluated by this module, and a new .geo
holding only those statements with their numbers is written under a fixed name into
a private temporary folder, where gmsh runs with that folder as its home, under a
time and a memory limit. A .msh is read by meshio's gmsh reader (pure Python, no
format guessing). Files must lie inside the scene's folder.
"""

import math
import os
import re
import resource
import shutil
import subprocess
import tempfile
from pathlib import Path

from .errors import SceneError

MAX_GEO_BYTES = 1_000_000          # a hand-written outline is a few kB
MAX_MSH_BYTES = 50_000_000
MAX_ENTITIES = 20_000              # points, curves, loops and surfaces together
MAX_EXPRESSION_DEPTH = 50
GMSH_MEMORY_MB = 2048


# ---------------------------------------------------------------- files inside the scene's folder

def file_inside(base_dir, name, where, suffixes):
    """The path of `name` relative to the scene's folder; refused when it is absolute, leaves
    that folder (.., a symlink pointing out) or is not a file with one of the suffixes."""
    if not isinstance(name, str) or not name or "\0" in name:
        raise SceneError(f"{where}: required (a {' or '.join(suffixes)} file, relative to the scene file)")
    relative = Path(name)
    if relative.is_absolute():
        raise SceneError(f"{where}: {name!r} is an absolute path; name a file inside the scene's folder")
    base = Path(base_dir).resolve()
    path = (base / relative).resolve()
    if not path.is_relative_to(base):
        raise SceneError(f"{where}: {name!r} lies outside the scene's folder {base}")
    if path.suffix not in suffixes or not path.is_file():
        raise SceneError(f"{where}: {name!r} is not a {' or '.join(suffixes)} file in the scene's folder")
    return path


# ---------------------------------------------------------------- .geo: tokens

TOKEN = re.compile(r"""
    (?P<space>\s+) | (?P<comment>//[^\n]*|/\*.*?\*/) |
    (?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?) |
    (?P<name>[A-Za-z_][A-Za-z0-9_]*) | (?P<string>"[A-Za-z0-9_ .-]{0,64}") |
    (?P<punct>[(){}\[\]=;,+\-*/^:.])
""", re.VERBOSE | re.DOTALL)


def tokens(text, where):
    out, pos, line = [], 0, 1
    while pos < len(text):
        match = TOKEN.match(text, pos)
        if match is None:
            raise SceneError(f"{where}: line {line}: the character {text[pos]!r} is refused (not part of the "
                             f"geometry statements a scene may use)")
        kind = match.lastgroup
        if kind not in ("space", "comment"):
            out.append((kind, match.group(), line))
        line += match.group().count("\n")
        pos = match.end()
    return out


# ---------------------------------------------------------------- .geo: the allowed statements

CURVES = {"Line": 2, "Circle": 3, "Ellipse": 4, "Spline": None, "BSpline": None}   # point counts
FUNCTIONS = {"Sqrt": math.sqrt, "Sin": math.sin, "Cos": math.cos, "Tan": math.tan, "Atan": math.atan,
             "Exp": math.exp, "Log": math.log, "Fabs": abs, "Abs": abs, "Atan2": math.atan2,
             "Hypot": math.hypot}
MESH_OPTIONS = ("CharacteristicLengthMax", "CharacteristicLengthMin", "CharacteristicLengthFactor",
                "MeshSizeMax", "MeshSizeMin", "MeshSizeFactor")
ALLOWED = ("variables (name = number), DefineConstant[...], Point, Line, Circle, Ellipse, Spline, BSpline, "
           "Curve Loop, Line Loop, Plane Surface, Surface, Physical Point/Curve/Line/Surface, "
           "Characteristic Length{...}, MeshSize{...}, Mesh.MeshSizeMax/Min/Factor (and the "
           "CharacteristicLength forms), Point{...} In Surface{...}")


class GeoReader:
    """Reads the allowed statements of a .geo into plain records (numbers and ids)."""

    def __init__(self, text, where):
        self.where = where
        self.toks = tokens(text, where)
        self.pos = 0
        self.variables = {"Pi": math.pi}
        self.records = []       # (kind, payload) in file order

    # -- token helpers
    def peek(self, offset=0):
        k = self.pos + offset
        return self.toks[k] if k < len(self.toks) else ("end", "", self.toks[-1][2] if self.toks else 1)

    def fail(self, message):
        raise SceneError(f"{self.where}: line {self.peek()[2]}: {message}")

    def take(self, value=None, kind=None):
        tok = self.peek()
        if (value is not None and tok[1] != value) or (kind is not None and tok[0] != kind):
            self.fail(f"expected {value or kind}, found {tok[1] or 'the end of the file'!r}")
        self.pos += 1
        return tok[1]

    def accept(self, value):
        if self.peek()[1] == value:
            self.pos += 1
            return True
        return False

    # -- expressions: numbers, variables, Pi, + - * / ^, parentheses, a few functions
    def expression(self, depth=0):
        if depth > MAX_EXPRESSION_DEPTH:
            self.fail(f"expression nested deeper than {MAX_EXPRESSION_DEPTH}")
        value = self.term(depth)
        while self.peek()[1] in ("+", "-"):
            op = self.take()
            right = self.term(depth)
            value = value + right if op == "+" else value - right
        return self.finite(value)

    def term(self, depth):
        value = self.power(depth)
        while self.peek()[1] in ("*", "/"):
            op = self.take()
            right = self.power(depth)
            if op == "/" and right == 0:
                self.fail("division by zero")
            value = value * right if op == "*" else value / right
        return self.finite(value)

    def power(self, depth):
        base = self.unary(depth)
        if self.accept("^"):
            exponent = self.power(depth + 1)
            try:
                return self.finite(math.pow(base, exponent))
            except (OverflowError, ValueError):
                self.fail("a power out of range")
        return base

    def unary(self, depth):
        if self.accept("-"):
            return -self.unary(depth + 1)
        if self.accept("+"):
            return self.unary(depth + 1)
        kind, text, _ = self.peek()
        if kind == "number":
            self.pos += 1
            return self.finite(float(text))
        if text == "(":
            self.pos += 1
            value = self.expression(depth + 1)
            self.take(")")
            return value
        if kind == "name" and text in FUNCTIONS:
            self.pos += 1
            self.take("[")     # gmsh writes Sqrt[x]
            args = [self.expression(depth + 1)]
            while self.accept(","):
                args.append(self.expression(depth + 1))
            self.take("]")
            try:
                return self.finite(FUNCTIONS[text](*args))
            except (TypeError, ValueError, OverflowError):
                self.fail(f"{text} of {args} is not defined")
        if kind == "name" and text in self.variables:
            self.pos += 1
            return self.variables[text]
        self.fail(f"{text!r} is not a number, a variable defined above or one of "
                  f"{', '.join(sorted(FUNCTIONS))}")

    def finite(self, value):
        if not math.isfinite(value):
            self.fail("the value is not finite")
        return value

    def integer(self):
        value = self.expression()
        if value != int(value) or not 0 <= value < 10 ** 9:
            self.fail(f"an entity id must be a whole number in [0, 1e9), got {value!r}")
        return int(value)

    def id_list(self, closing="}"):
        """{a, b, c:d, ...}: ids, with gmsh's ranges a:b (bounded by MAX_ENTITIES)."""
        ids = []
        if self.peek()[1] == closing:
            return ids
        while True:
            first = self.expression()
            if self.accept(":"):
                last = self.expression()
                if first != int(first) or last != int(last) or not 0 <= last - first < MAX_ENTITIES:
                    self.fail("a range a:b needs whole numbers a <= b, fewer than 20,000 apart")
                ids.extend(range(int(first), int(last) + 1))
            else:
                if first != int(first):
                    self.fail(f"an entity id must be a whole number, got {first!r}")
                ids.append(int(first))
            if len(ids) > MAX_ENTITIES:
                self.fail(f"more than {MAX_ENTITIES} entities")
            if not self.accept(","):
                return ids

    def braced(self, read):
        """{ ... } read by read()."""
        self.take("{")
        value = read()
        self.take("}")
        return value

    def numbers(self):
        values = [self.expression()]
        while self.accept(","):
            values.append(self.expression())
        return values

    # -- statements
    def read(self):
        while self.peek()[0] != "end":
            self.statement()
            if len(self.records) > MAX_ENTITIES:
                self.fail(f"more than {MAX_ENTITIES} statements")
        return self.records

    def statement(self):
        kind, word, _ = self.peek()
        following = self.peek(1)[1]
        if kind != "name":
            self.fail(f"{word!r} is refused: a statement starts with a keyword or a variable name")
        if word == "DefineConstant":
            self.pos += 1
            self.take("[")
            while True:
                name = self.take(kind="name")
                self.take("=")
                self.define(name, self.expression())
                if not self.accept(","):
                    break
            self.take("]")
        elif word == "Point" and following == "(":
            self.pos += 1
            ident = self.entity_id()
            self.take("=")
            values = self.braced(self.numbers)
            if len(values) not in (3, 4):
                self.fail("Point(id) = {x, y, z} or {x, y, z, size}")
            if len(values) == 4 and values[3] <= 0:
                self.fail("a point's mesh size must be > 0")
            self.records.append(("Point", (ident, values)))
        elif word == "Point" and following == "{":
            self.pos += 1
            points = self.braced(self.id_list)
            self.take("In")
            self.take("Surface")
            surface = self.braced(self.integer)
            self.records.append(("PointInSurface", (points, surface)))
        elif word in CURVES:
            self.pos += 1
            ident = self.entity_id()
            self.take("=")
            points = self.braced(self.id_list)
            count = CURVES[word]
            if (count is not None and len(points) != count) or len(points) < 2:
                self.fail(f"{word} takes {count or 'at least 2'} point ids")
            self.records.append((word, (ident, points)))
        elif word in ("Curve", "Line") and following == "Loop":
            self.pos += 2
            ident = self.entity_id()
            self.take("=")
            curves = self.braced(self.id_list)
            self.records.append(("Curve Loop", (ident, curves)))
        elif word == "Plane" or (word == "Surface" and following == "("):
            self.pos += 1
            if word == "Plane":
                self.take("Surface")
            ident = self.entity_id()
            self.take("=")
            loops = self.braced(self.id_list)
            self.records.append(("Plane Surface" if word == "Plane" else "Surface", (ident, loops)))
        elif word == "Physical":
            self.pos += 1
            what = self.take(kind="name")
            if what not in ("Point", "Curve", "Line", "Surface"):
                self.fail(f"Physical {what}: only Physical Point, Curve, Line or Surface")
            self.take("(")
            label = None
            if self.peek()[0] == "string":
                label = self.take()
                ident = self.integer() if self.accept(",") else None
            else:
                ident = self.integer()
            self.take(")")
            self.take("=")
            members = self.braced(self.id_list)
            self.records.append(("Physical", ("Curve" if what == "Line" else what, label, ident, members)))
        elif word in ("Characteristic", "MeshSize"):
            self.pos += 1
            if word == "Characteristic":
                self.take("Length")
            points = self.braced(self.id_list)
            self.take("=")
            size = self.expression()
            if size <= 0:
                self.fail("a mesh size must be > 0")
            self.records.append(("MeshSize", (points, size)))
        elif word == "Mesh" and following == ".":
            self.pos += 2
            option = self.take(kind="name")
            if option not in MESH_OPTIONS:
                self.fail(f"Mesh.{option}: only the mesh-size options {', '.join(MESH_OPTIONS)}")
            self.take("=")
            value = self.expression()
            if value <= 0:
                self.fail(f"Mesh.{option} must be > 0")
            self.records.append(("MeshOption", (option, value)))
        elif following == "=" and word not in self.reserved():
            self.pos += 2
            self.define(word, self.expression())
        else:
            self.fail(f"{word!r} is refused: a scene's geometry may use only {ALLOWED}")
        self.take(";")

    def entity_id(self):
        self.take("(")
        ident = self.integer()
        self.take(")")
        return ident

    def define(self, name, value):
        if name in self.reserved() or name in FUNCTIONS:
            self.fail(f"{name!r} is a gmsh keyword, not a variable name")
        if len(self.variables) > 1000:
            self.fail("more than 1000 variables")
        self.variables[name] = value

    @staticmethod
    def reserved():
        return {"Point", "Line", "Circle", "Ellipse", "Spline", "BSpline", "Curve", "Loop", "Plane",
                "Surface", "Physical", "Characteristic", "Length", "MeshSize", "Mesh", "In", "Pi",
                "DefineConstant"}


def read_geo(path, where):
    """The records of a .geo file (an allow-list of geometry statements), or one SceneError."""
    try:
        size = path.stat().st_size
        if size > MAX_GEO_BYTES:
            raise SceneError(f"{where}: {path.name} is {size} bytes; a geometry file may hold at most "
                             f"{MAX_GEO_BYTES}")
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise SceneError(f"{where}: {path.name} is not UTF-8 text") from None
    except OSError as exc:
        raise SceneError(f"{where}: cannot read {path.name} ({exc.strerror})") from None
    records = GeoReader(text, where).read()
    if not any(kind == "Point" for kind, _ in records):
        raise SceneError(f"{where}: {path.name} defines no Point")
    return records


def geo_text(records):
    """A .geo holding only the records, every number written out (no variables, no other statement)."""
    def ids(values):
        return ", ".join(str(v) for v in values)

    def num(value):
        return repr(float(value))

    lines = []
    for kind, payload in records:
        if kind == "Point":
            ident, values = payload
            lines.append(f"Point({ident}) = {{{', '.join(num(v) for v in values)}}};")
        elif kind == "PointInSurface":
            points, surface = payload
            lines.append(f"Point{{{ids(points)}}} In Surface{{{surface}}};")
        elif kind in CURVES or kind in ("Curve Loop", "Plane Surface", "Surface"):
            ident, members = payload
            lines.append(f"{kind}({ident}) = {{{ids(members)}}};")
        elif kind == "Physical":
            what, label, ident, members = payload
            head = ", ".join(x for x in (label, None if ident is None else str(ident)) if x is not None)
            lines.append(f"Physical {what}({head}) = {{{ids(members)}}};")
        elif kind == "MeshSize":
            points, size = payload
            lines.append(f"MeshSize{{{ids(points)}}} = {num(size)};")
        elif kind == "MeshOption":
            option, value = payload
            lines.append(f"Mesh.{option} = {num(value)};")
    return "\n".join(lines) + "\n"


def geo_extent(records, axis=None):
    """The largest side of the box holding the .geo's points (or its side along one axis)."""
    points = [payload[1] for kind, payload in records if kind == "Point"]
    spans = [max(p[i] for p in points) - min(p[i] for p in points) for i in range(3)]
    return max(spans) if axis is None else spans[axis]


# ---------------------------------------------------------------- running gmsh on the data

def limit_memory(megabytes):
    def apply():
        limit = int(megabytes) * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    return apply


def mesh_geo(records, dim, size, where, out_file, seconds):
    """Mesh the records with gmsh (dim 1: the outline; 2: the surface) at mesh size `size` into
    out_file (MSH 2.2), in a private temporary folder, within `seconds` and GMSH_MEMORY_MB."""
    gmsh = shutil.which("gmsh")
    if gmsh is None:
        raise SceneError(f"{where}: gmsh not found (run 'make setup')")
    with tempfile.TemporaryDirectory(prefix="fdcontact-gmsh-") as tmp:
        geo = Path(tmp) / "shape.geo"
        geo.write_text(geo_text(records))
        msh = Path(tmp) / "shape.msh"
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": tmp, "LC_ALL": "C"}
        command = [gmsh, str(geo), f"-{dim}", "-clmax", repr(float(size)), "-format", "msh22", "-v", "2",
                   "-nopopup", "-o", str(msh)]
        try:
            proc = subprocess.run(command, cwd=tmp, env=env, capture_output=True, text=True, errors="replace",
                                  timeout=seconds, preexec_fn=limit_memory(GMSH_MEMORY_MB))
        except subprocess.TimeoutExpired:
            raise SceneError(f"{where}: gmsh did not finish within {seconds:g} s (limits.gmsh_s; a larger "
                             f"mesh size helps)") from None
        if proc.returncode != 0 or not msh.is_file():
            tail = " ".join((proc.stdout + proc.stderr).strip().splitlines()[-3:])
            raise SceneError(f"{where}: gmsh could not mesh the geometry (exit {proc.returncode}): {tail}")
        shutil.move(str(msh), out_file)
    return out_file


def read_msh(path, where):
    """A meshio mesh from a .msh file (gmsh's own reader of meshio, no format guessing)."""
    import meshio.gmsh

    try:
        size = Path(path).stat().st_size
    except OSError as exc:
        raise SceneError(f"{where}: cannot read {Path(path).name} ({exc.strerror})") from None
    if size > MAX_MSH_BYTES:
        raise SceneError(f"{where}: {Path(path).name} is {size} bytes; a mesh file may hold at most {MAX_MSH_BYTES}")
    try:
        return meshio.gmsh.read(str(path))
    except Exception as exc:   # meshio raises many types on a malformed file
        detail = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        raise SceneError(f"{where}: {Path(path).name} is not a readable gmsh mesh ({detail})") from None


MIN_SIZE_RATIO = 2000     # no mesh size below 1/2000 of the geometry's extent


def check_mesh_sizes(records, where):
    """Mesh sizes inside the file (point sizes, MeshSize{...}, Mesh.MeshSizeMin/Max) are not
    far below the geometry's extent: gmsh would mesh for minutes."""
    smallest = geo_extent(records) / MIN_SIZE_RATIO
    for kind, payload in records:
        sizes = []
        if kind == "Point" and len(payload[1]) == 4:
            sizes = [payload[1][3]]
        elif kind == "MeshSize":
            sizes = [payload[1]]
        elif kind == "MeshOption" and "Factor" not in payload[0]:
            sizes = [payload[1]]
        elif kind == "MeshOption" and not 1e-3 <= payload[1] <= 1e3:
            raise SceneError(f"{where}: Mesh.{payload[0]} = {payload[1]:g} must lie in [0.001, 1000]")
        for size in sizes:
            if size < smallest:
                raise SceneError(f"{where}: a mesh size {size:g} below 1/{MIN_SIZE_RATIO} of the geometry's "
                                 f"extent ({smallest:.3g})")
