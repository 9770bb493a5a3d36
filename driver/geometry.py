"""Shapes of a scene: a tree of primitives and boolean operations, in 2D or 3D.

A shape is a TOML table with a `type`: a primitive (2D: disk, ellipse, box,
half_plane, polygon, gmsh; 3D: ball, ellipsoid, box, cylinder, half_space, surface;
both: expression) or a boolean (union, intersection, difference: `of = [shape, ...]`).
Any shape may carry `translate` (a vector) and `rotate` (degrees: one angle in 2D;
[about x, about y, about z] in 3D, applied in that order), which place it: a point
x of the scene is tested at R^T (x - translate) in the shape's own coordinates.

Each shape is a level set phi (< 0 inside; a signed distance where the primitive
allows). This module checks a tree (one SceneError naming the key), evaluates it
with numpy (for the driver's checks: inside the box, no overlap at the start) and
writes it as a FreeFEM expression built from the primitives of
freefem/lib/fd2d/levelset.idp and freefem/lib/fd3d/levelset.idp, so the solver and
the driver evaluate the same formula. Expressions are parsed with Python's ast
and rebuilt from an allowed set of names: the scene's text never reaches FreeFEM.
"""

import ast
import math

import numpy as np

from .errors import SceneError
from .schema import finite_float, finite_floats

PRIMITIVES = {
    2: ("disk", "ellipse", "box", "half_plane", "polygon", "gmsh", "expression"),
    3: ("ball", "ellipsoid", "box", "cylinder", "half_space", "surface", "expression"),
}
BOOLEANS = ("union", "intersection", "difference")
MAX_POLYGON_EDGES = 400
# Limits before work: a shape tree's depth, an expression's nesting, and the FreeFEM code a
# shape may become (nested rotations multiply it: each level repeats its coordinates).
MAX_TREE_DEPTH = 16
MAX_EXPRESSION_DEPTH = 100
MAX_CODE_CHARS = 200_000


def fmt(value):
    """A float in full precision, as FreeFEM reads it."""
    return repr(float(value))


class Shape:
    """A node of the tree; subclasses give phi (numpy) and code (FreeFEM)."""

    def __init__(self, dim, translate, rotation):
        self.dim = dim
        self.translate = translate
        self.rotation = rotation          # None or a dim x dim matrix R

    def local_np(self, pts):
        pts = [p - t for p, t in zip(pts, self.translate)] if self.translate else list(pts)
        if self.rotation is None:
            return pts
        r = self.rotation
        return [sum(r[k][i] * pts[k] for k in range(self.dim)) for i in range(self.dim)]

    def local_code(self, coords):
        coords = [f"(({c}) - {fmt(t)})" for c, t in zip(coords, self.translate)] if self.translate else list(coords)
        if self.rotation is None:
            return coords
        r = self.rotation
        # each coordinate in parentheses: a macro argument may be an expression (qx[q] + t*nx)
        return ["(" + " + ".join(f"{fmt(r[k][i])}*({coords[k]})" for k in range(self.dim)) + ")"
                for i in range(self.dim)]

    def phi(self, *pts):
        return self.phi_local(*self.local_np(pts))

    def code(self, *coords):
        coords = self.local_code(coords)
        if sum(len(c) for c in coords) > MAX_CODE_CHARS:
            raise SceneError(f"the shape tree becomes more than {MAX_CODE_CHARS:,} characters of FreeFEM code "
                             f"(nested rotated shapes repeat their coordinates): flatten the tree")
        text = self.code_local(*coords)
        if len(text) > MAX_CODE_CHARS:
            raise SceneError(f"the shape tree becomes more than {MAX_CODE_CHARS:,} characters of FreeFEM code: "
                             f"use fewer or simpler shapes")
        return text

    def measure(self):
        """Exact area (2D) or volume (3D) of {phi < 0}, or None (rigid placement keeps it)."""
        return None

    def bounds(self):
        """A box (lo, hi) holding the placed shape, or None when it is unbounded (half-spaces,
        expressions, booleans)."""
        if not hasattr(self, "bounds_local"):
            return None
        lo, hi = self.bounds_local()
        corners = np.array(np.meshgrid(*[[l, h] for l, h in zip(lo, hi)], indexing="ij")).reshape(self.dim, -1)
        if self.rotation is not None:
            corners = np.array(self.rotation) @ corners
        if self.translate:
            corners = corners + np.array(self.translate)[:, None]
        return corners.min(axis=1), corners.max(axis=1)


# ---------------------------------------------------------------- primitives

class Disk(Shape):
    def __init__(self, dim, translate, rotation, centre, radius):
        super().__init__(dim, translate, rotation)
        self.centre, self.radius = centre, radius

    def phi_local(self, *p):
        return np.sqrt(sum((pi - ci) ** 2 for pi, ci in zip(p, self.centre))) - self.radius

    def code_local(self, *c):
        name = "lsDisk" if self.dim == 2 else "lsBall"
        return f"{name}({', '.join(c)}, {', '.join(map(fmt, self.centre))}, {fmt(self.radius)})"

    def measure(self):
        return math.pi * self.radius ** 2 if self.dim == 2 else 4.0 / 3.0 * math.pi * self.radius ** 3

    def bounds_local(self):
        return [c - self.radius for c in self.centre], [c + self.radius for c in self.centre]


class Ellipse(Shape):
    """phi = min(a_i) (|((x - c)/a)| - 1): the zero set is the ellipse, |grad phi| between 1 and max/min."""

    def __init__(self, dim, translate, rotation, centre, axes):
        super().__init__(dim, translate, rotation)
        self.centre, self.axes = centre, axes

    def phi_local(self, *p):
        s = np.sqrt(sum(((pi - ci) / ai) ** 2 for pi, ci, ai in zip(p, self.centre, self.axes)))
        return min(self.axes) * (s - 1.0)

    def code_local(self, *c):
        name = "lsEllipse" if self.dim == 2 else "lsEllipsoid"
        return f"{name}({', '.join(c)}, {', '.join(map(fmt, self.centre))}, {', '.join(map(fmt, self.axes))})"

    def measure(self):
        return math.prod(self.axes) * (math.pi if self.dim == 2 else 4.0 / 3.0 * math.pi)

    def bounds_local(self):
        return [c - a for c, a in zip(self.centre, self.axes)], [c + a for c, a in zip(self.centre, self.axes)]


class Box(Shape):
    """Axis-aligned box [lo, hi] with corners (2D) or edges (3D) rounded by r: exact signed distance."""

    def __init__(self, dim, translate, rotation, lo, hi, radius):
        super().__init__(dim, translate, rotation)
        self.lo, self.hi, self.radius = lo, hi, radius

    def phi_local(self, *p):
        r = self.radius
        d = [np.maximum(lo + r - pi, pi - hi + r) for pi, lo, hi in zip(p, self.lo, self.hi)]
        inside = np.minimum(np.maximum.reduce(d), 0.0)
        outside = np.sqrt(sum(np.maximum(di, 0.0) ** 2 for di in d))
        return inside + outside - r

    def code_local(self, *c):
        r = self.radius
        limits = ", ".join(f"{fmt(lo + r)}, {fmt(hi - r)}" for lo, hi in zip(self.lo, self.hi))
        name = "lsRoundedBox" if self.dim == 2 else "lsRoundedBox3"
        return f"{name}({', '.join(c)}, {limits}, {fmt(r)})"

    def measure(self):
        r = self.radius
        inner = [hi - lo - 2 * r for lo, hi in zip(self.lo, self.hi)]
        if self.dim == 2:
            return inner[0] * inner[1] + 2 * r * (inner[0] + inner[1]) + math.pi * r ** 2
        a, b, c = inner     # Steiner's formula for the inner box grown by a ball of radius r
        return a * b * c + 2 * (a * b + b * c + a * c) * r + math.pi * (a + b + c) * r ** 2 + 4 / 3 * math.pi * r ** 3

    def bounds_local(self):
        return list(self.lo), list(self.hi)


class HalfSpace(Shape):
    """{(x - point).normal < 0}: the normal points out of the body."""

    def __init__(self, dim, translate, rotation, point, normal):
        super().__init__(dim, translate, rotation)
        self.point, self.normal = point, normal

    def phi_local(self, *p):
        n = math.sqrt(sum(v * v for v in self.normal))
        return sum((pi - ci) * ni for pi, ci, ni in zip(p, self.point, self.normal)) / n

    def code_local(self, *c):
        name = "lsHalfPlane" if self.dim == 2 else "lsHalfSpace"
        return f"{name}({', '.join(c)}, {', '.join(map(fmt, self.point))}, {', '.join(map(fmt, self.normal))})"


class Cylinder(Shape):
    """Finite cylinder: centre, unit axis, radius, length (flat ends)."""

    def __init__(self, dim, translate, rotation, centre, axis, radius, length):
        super().__init__(dim, translate, rotation)
        n = math.sqrt(sum(a * a for a in axis))
        self.centre, self.axis, self.radius, self.length = centre, [a / n for a in axis], radius, length

    def phi_local(self, *p):
        d = [pi - ci for pi, ci in zip(p, self.centre)]
        along = sum(di * ai for di, ai in zip(d, self.axis))
        radial = np.sqrt(np.maximum(sum(di * di for di in d) - along ** 2, 0.0))
        qa, qb = radial - self.radius, np.abs(along) - self.length / 2
        return np.minimum(np.maximum(qa, qb), 0.0) + np.sqrt(np.maximum(qa, 0.0) ** 2 + np.maximum(qb, 0.0) ** 2)

    def code_local(self, *c):
        return (f"lsCylinder({', '.join(c)}, {', '.join(map(fmt, self.centre))}, {', '.join(map(fmt, self.axis))}, "
                f"{fmt(self.radius)}, {fmt(self.length / 2)})")

    def measure(self):
        return math.pi * self.radius ** 2 * self.length

    def bounds_local(self):
        # along each axis e_i: the half-length times |a_i| plus the end disks' reach r sqrt(1 - a_i^2)
        ext = [abs(a) * self.length / 2 + self.radius * math.sqrt(max(1.0 - a * a, 0.0)) for a in self.axis]
        return [c - e for c, e in zip(self.centre, ext)], [c + e for c, e in zip(self.centre, ext)]


class Polygon(Shape):
    """Exact signed distance to a set of closed loops (holes allowed): the distance to the
    nearest edge, negative where a ray crosses an odd number of edges."""

    def __init__(self, dim, translate, rotation, loops):
        super().__init__(dim, translate, rotation)
        self.loops = loops
        self.edges = [(loop[i - 1], loop[i]) for loop in loops for i in range(len(loop))]

    def phi_local(self, x, y):
        d2 = np.full(np.shape(x), np.inf)
        sign = np.ones(np.shape(x))
        for (ax, ay), (bx, by) in self.edges:
            ex, ey = bx - ax, by - ay
            wx, wy = x - ax, y - ay
            t = np.clip((wx * ex + wy * ey) / (ex * ex + ey * ey), 0.0, 1.0)
            d2 = np.minimum(d2, (wx - t * ex) ** 2 + (wy - t * ey) ** 2)
            c1, c2, c3 = y >= ay, y < by, ex * wy > ey * wx
            flip = (c1 & c2 & c3) | (~c1 & ~c2 & ~c3)
            sign = np.where(flip, -sign, sign)
        return sign * np.sqrt(d2)

    def code_local(self, x, y):
        dist = None
        sign = []
        for (ax, ay), (bx, by) in self.edges:
            args = f"{x}, {y}, {fmt(ax)}, {fmt(ay)}, {fmt(bx)}, {fmt(by)}"
            term = f"lsSegmentDist2({args})"
            dist = term if dist is None else f"min({dist}, {term})"
            sign.append(f"lsEdgeSign({args})")
        return f"(sqrt({dist})*{'*'.join(sign)})"

    def measure(self):
        areas = [0.5 * sum(ax * by - bx * ay for (ax, ay), (bx, by) in zip(loop[-1:] + loop[:-1], loop))
                 for loop in self.loops]
        if len(self.loops) == 1:
            return abs(areas[0])
        # nested loops: inside where the crossing count is odd; holes are loops inside the largest
        order = sorted(range(len(areas)), key=lambda i: -abs(areas[i]))
        outer = order[0]
        total = abs(areas[outer])
        for i in order[1:]:
            x0, y0 = self.loops[i][0]
            probe = Polygon(2, None, None, [self.loops[outer]])
            if probe.phi_local(np.array([x0]), np.array([y0]))[0] > 1e-12:
                return None
            total -= abs(areas[i])
        return total

    def bounds_local(self):
        xs = [p[0] for loop in self.loops for p in loop]
        ys = [p[1] for loop in self.loops for p in loop]
        return [min(xs), min(ys)], [max(xs), max(ys)]


class Surface(Shape):
    """A closed triangulated surface read from a file (driver/surface_input.py): the exact signed
    distance to its triangles, the sign from the angle-weighted pseudo-normal of the nearest
    feature. FreeFEM evaluates it with the plugin freefem/plugins/surface_distance.cpp on a table
    written beside the scene module; numpy's side is libigl's signed_distance with the same
    rule."""

    def __init__(self, dim, translate, rotation, points, triangles):
        from . import surface_input

        super().__init__(dim, translate, rotation)
        self.points, self.triangles = points, triangles
        self.table = surface_input.surface_table(points, triangles)
        self.table_name = surface_input.table_name(self.table)
        self.variable = "surfaceTable" + self.table_name[len("surface-"):-len(".txt")]
        self.volume = surface_input.enclosed_volume(points, triangles)

    def phi_local(self, x, y, z):
        import igl

        shape = np.broadcast_shapes(np.shape(x), np.shape(y), np.shape(z))
        query = np.column_stack([np.broadcast_to(c, shape).reshape(-1) for c in (x, y, z)]).astype(float)
        distance = igl.signed_distance(query, self.points, self.triangles,
                                       sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0]
        return distance.reshape(shape)

    def code_local(self, x, y, z):
        return f"surfaceDistance({self.variable}, {x}, {y}, {z})"

    def measure(self):
        return self.volume

    def bounds_local(self):
        return list(self.points.min(axis=0)), list(self.points.max(axis=0))


def surfaces_in(shape):
    """The Surface shapes of a tree."""
    if isinstance(shape, Surface):
        return [shape]
    return [s for child in getattr(shape, "children", []) for s in surfaces_in(child)]


# ---------------------------------------------------------------- expressions

FUNCTIONS = {"sqrt": 1, "abs": 1, "exp": 1, "log": 1, "sin": 1, "cos": 1, "tan": 1, "atan": 1, "tanh": 1,
             "atan2": 2, "min": 2, "max": 2, "pow": 2}
NUMPY = {"sqrt": np.sqrt, "abs": np.abs, "exp": np.exp, "log": np.log, "sin": np.sin, "cos": np.cos,
         "tan": np.tan, "atan": np.arctan, "tanh": np.tanh, "atan2": np.arctan2, "min": np.minimum,
         "max": np.maximum, "pow": np.power}
BINARY = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "^"}


class Expression(Shape):
    def __init__(self, dim, translate, rotation, text, where):
        super().__init__(dim, translate, rotation)
        self.names = ("x", "y", "z")[:dim]
        if not isinstance(text, str) or not text.strip() or len(text) > 2000:
            raise SceneError(f"{where}: expected an expression in {', '.join(self.names)} (at most 2000 characters)")
        try:
            self.tree = ast.parse(text.replace("^", "**"), mode="eval").body
        except SyntaxError as exc:
            raise SceneError(f"{where}: not a valid expression ({exc.msg})") from None
        except (RecursionError, MemoryError):
            raise SceneError(f"{where}: the expression is nested too deep") from None
        self.where = where
        self.check(self.tree)

    def check(self, node, depth=0):
        where = self.where
        if depth > MAX_EXPRESSION_DEPTH:
            raise SceneError(f"{where}: the expression is nested more than {MAX_EXPRESSION_DEPTH} deep "
                             f"(a chain a + b + ... counts one level per term)")
        depth += 1
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                raise SceneError(f"{where}: only numbers, {', '.join(self.names)}, pi, + - * / ^ and "
                                 f"{', '.join(FUNCTIONS)} are allowed (found {node.value!r})")
            if finite_float(node.value) is None:
                raise SceneError(f"{where}: the number {str(node.value)[:20]}... is not a finite float")
        elif isinstance(node, ast.Name):
            if node.id not in self.names + ("pi",):
                raise SceneError(f"{where}: unknown name {node.id!r} (allowed: {', '.join(self.names)}, pi)")
        elif isinstance(node, ast.BinOp) and type(node.op) in BINARY:
            self.check(node.left, depth)
            self.check(node.right, depth)
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            self.check(node.operand, depth)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS:
            if node.keywords or len(node.args) != FUNCTIONS[node.func.id]:
                raise SceneError(f"{where}: {node.func.id} takes {FUNCTIONS[node.func.id]} argument(s)")
            for arg in node.args:
                self.check(arg, depth)
        else:
            raise SceneError(f"{where}: only numbers, {', '.join(self.names)}, pi, + - * / ^ and "
                             f"{', '.join(FUNCTIONS)} are allowed")

    def phi_local(self, *p):
        values = dict(zip(self.names, p), pi=math.pi)

        def ev(node):
            if isinstance(node, ast.Constant):
                return float(node.value)
            if isinstance(node, ast.Name):
                return values[node.id]
            if isinstance(node, ast.UnaryOp):
                return -ev(node.operand) if isinstance(node.op, ast.USub) else ev(node.operand)
            if isinstance(node, ast.Call):
                return NUMPY[node.func.id](*[ev(a) for a in node.args])
            a, b = ev(node.left), ev(node.right)
            return {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide,
                    ast.Pow: np.power}[type(node.op)](a, b)

        with np.errstate(all="ignore"):
            return ev(self.tree) + np.zeros(np.shape(p[0]))

    def code_local(self, *coords):
        values = dict(zip(self.names, coords), pi="pi")

        def out(node):
            if isinstance(node, ast.Constant):
                return f"({fmt(node.value)})"
            if isinstance(node, ast.Name):
                return f"({values[node.id]})"
            if isinstance(node, ast.UnaryOp):
                return f"(-{out(node.operand)})" if isinstance(node.op, ast.USub) else out(node.operand)
            if isinstance(node, ast.Call):
                return f"{node.func.id}({', '.join(out(a) for a in node.args)})"
            return f"({out(node.left)} {BINARY[type(node.op)]} {out(node.right)})"

        return out(self.tree)


# ---------------------------------------------------------------- booleans

class Boolean(Shape):
    def __init__(self, dim, translate, rotation, op, children):
        super().__init__(dim, translate, rotation)
        self.op, self.children = op, children

    def phi_local(self, *p):
        values = [c.phi(*p) for c in self.children]
        if self.op == "union":
            return np.minimum.reduce(values)
        if self.op == "intersection":
            return np.maximum.reduce(values)
        return np.maximum.reduce([values[0]] + [-v for v in values[1:]])

    def code_local(self, *c):
        parts = [child.code(*c) for child in self.children]
        name = {"union": "lsUnion", "intersection": "lsIntersection", "difference": "lsDifference"}[self.op]
        text = parts[0]
        for part in parts[1:]:
            text = f"{name}({text}, {part})"
        return text


# ---------------------------------------------------------------- reading a tree

def rotation_matrix(dim, rotate, where):
    if dim == 2:
        if finite_float(rotate) is None:
            raise SceneError(f"{where}: expected an angle in degrees")
        a = math.radians(rotate)
        return [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    angles = numbers(rotate, 3, where)
    cx, cy, cz = (math.cos(math.radians(a)) for a in angles)
    sx, sy, sz = (math.sin(math.radians(a)) for a in angles)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return (rz @ ry @ rx).tolist()


def numbers(value, length, where):
    if finite_floats(value, length) is None:
        raise SceneError(f"{where}: expected {length} finite numbers, got {str(value)[:80]}")
    return finite_floats(value, length)


def positive_number(value, where):
    if finite_float(value) is None or value <= 0:
        raise SceneError(f"{where}: must be a number > 0, got {str(value)[:40]}")
    return float(value)


ALLOWED_KEYS = {
    "disk": {"centre", "radius"}, "ball": {"centre", "radius"},
    "ellipse": {"centre", "semi_axes"}, "ellipsoid": {"centre", "semi_axes"},
    "box": {"min", "max", "corner_radius", "edge_radius"},
    "half_plane": {"point", "normal"}, "half_space": {"point", "normal"},
    "polygon": {"vertices"}, "gmsh": {"file", "size"}, "surface": {"file", "scale"},
    "cylinder": {"centre", "axis", "radius", "length"},
    "expression": {"phi"},
    "union": {"of"}, "intersection": {"of"}, "difference": {"of"},
}


# One line per shape type for the scene reference (docs/scenes.md, "Shapes").
SHAPE_DOCS = {
    "disk": ("2D", "centre = [x, y], radius", "exact signed distance"),
    "ball": ("3D", "centre = [x, y, z], radius", "exact signed distance"),
    "ellipse": ("2D", "centre, semi_axes = [a, b]", "min(a, b)(|((x - c)/a, (y - c)/b)| - 1): not a distance"),
    "ellipsoid": ("3D", "centre, semi_axes = [a, b, c]", "as the ellipse"),
    "box": ("2D, 3D", "min, max (corners), corner_radius (2D) or edge_radius (3D), default 0",
            "exact signed distance; the radius is below half the smallest side"),
    "half_plane": ("2D", "point, normal (outward, any length)", "{(x - point).normal < 0}"),
    "half_space": ("3D", "point, normal", "as half_plane"),
    "cylinder": ("3D", "centre, axis, radius, length", "finite, flat ends; exact signed distance"),
    "polygon": ("2D", "vertices = [[x, y], ...] (at least 3, at most 400 edges)",
                "exact signed distance to the closed polygon"),
    "gmsh": ("2D", "file (a .geo or .msh next to the scene), size (mesh size of the outline, default 0.02)",
             "the closed outline(s) in z = 0 meshed by gmsh, as a polygon; .geo files that run programs "
             "or write files are refused"),
    "surface": ("3D", "file (an .stl, ascii or binary, or a gmsh .msh of triangles, next to the scene), scale "
                "(a factor on its coordinates, default 1)",
                "exact signed distance to a closed, consistently oriented triangulated surface (at most "
                "50,000 triangles; the run's volume is the one it encloses)"),
    "expression": ("2D, 3D", "phi = \"...\" in x, y (z): numbers, pi, + - * / ^ and sqrt abs exp log sin "
                   "cos tan atan tanh atan2 min max pow", "any level set (< 0 inside); parsed and rebuilt, "
                   "never copied"),
    "union": ("2D, 3D", "of = [shape, ...]", "min of the level sets"),
    "intersection": ("2D, 3D", "of = [shape, shape, ...]", "max of the level sets"),
    "difference": ("2D, 3D", "of = [shape, shape, ...]", "the first minus the others"),
}


def read_shape(data, dim, where, base_dir=None, mesher=None, depth=0):
    """A validated Shape from a scene table (where: 'file: key body1.shape')."""
    if depth > MAX_TREE_DEPTH:
        raise SceneError(f"{where}: shapes nested more than {MAX_TREE_DEPTH} deep")
    if not isinstance(data, dict):
        raise SceneError(f"{where}: expected a table with a 'type' (e.g. {{ type = \"disk\", ... }})")
    kind = data.get("type")
    known = PRIMITIVES[dim] + BOOLEANS
    if kind not in known:
        raise SceneError(f"{where}.type: unknown shape {kind!r} in {dim}D (known: {', '.join(known)})")
    extra = set(data) - ALLOWED_KEYS[kind] - {"type", "translate", "rotate"}
    if extra:
        raise SceneError(f"{where}: unknown key(s) {', '.join(sorted(extra))} for a {kind} "
                         f"(known: {', '.join(sorted(ALLOWED_KEYS[kind] | {'translate', 'rotate'}))})")
    translate = numbers(data["translate"], dim, f"{where}.translate") if "translate" in data else None
    rotation = rotation_matrix(dim, data["rotate"], f"{where}.rotate") if "rotate" in data else None
    args = (dim, translate, rotation)

    def need(key):
        if key not in data:
            raise SceneError(f"{where}.{key}: required for a {kind}")
        return data[key]

    if kind in ("disk", "ball"):
        return Disk(*args, numbers(need("centre"), dim, f"{where}.centre"),
                    positive_number(need("radius"), f"{where}.radius"))
    if kind in ("ellipse", "ellipsoid"):
        axes = numbers(need("semi_axes"), dim, f"{where}.semi_axes")
        if min(axes) <= 0:
            raise SceneError(f"{where}.semi_axes: must be > 0, got {axes}")
        return Ellipse(*args, numbers(need("centre"), dim, f"{where}.centre"), axes)
    if kind == "box":
        lo, hi = numbers(need("min"), dim, f"{where}.min"), numbers(need("max"), dim, f"{where}.max")
        if any(h <= l for l, h in zip(lo, hi)):
            raise SceneError(f"{where}: empty box (need max > min in every direction, got {lo} .. {hi})")
        key = "corner_radius" if dim == 2 else "edge_radius"
        radius = data.get(key, 0.0)
        if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not 0 <= radius < min(
                h - l for l, h in zip(lo, hi)) / 2:
            raise SceneError(f"{where}.{key}: must lie in [0, half the smallest side), got {radius!r}")
        return Box(*args, lo, hi, float(radius))
    if kind in ("half_plane", "half_space"):
        normal = numbers(need("normal"), dim, f"{where}.normal")
        if math.sqrt(sum(n * n for n in normal)) == 0:
            raise SceneError(f"{where}.normal: must not be zero")
        return HalfSpace(*args, numbers(need("point"), dim, f"{where}.point"), normal)
    if kind == "cylinder":
        axis = numbers(need("axis"), 3, f"{where}.axis")
        if math.sqrt(sum(a * a for a in axis)) == 0:
            raise SceneError(f"{where}.axis: must not be zero")
        return Cylinder(*args, numbers(need("centre"), 3, f"{where}.centre"), axis,
                        positive_number(need("radius"), f"{where}.radius"),
                        positive_number(need("length"), f"{where}.length"))
    if kind == "polygon":
        vertices = need("vertices")
        if not isinstance(vertices, list) or len(vertices) < 3:
            raise SceneError(f"{where}.vertices: expected a list of at least 3 points [[x, y], ...]")
        loop = [tuple(numbers(v, 2, f"{where}.vertices.{i}")) for i, v in enumerate(vertices)]
        return checked_polygon(Polygon(*args, [loop]), f"{where}.vertices")
    if kind == "gmsh":
        if mesher is None or base_dir is None:
            raise SceneError(f"{where}: gmsh shapes need the driver (a scene file)")
        loops = mesher(data, base_dir, f"{where}")
        return checked_polygon(Polygon(*args, loops), f"{where}.file")
    if kind == "surface":
        from .surface_input import read_surface

        if base_dir is None:
            raise SceneError(f"{where}: surface shapes need the driver (a scene file)")
        scale = positive_number(data.get("scale", 1.0), f"{where}.scale")
        return Surface(*args, *read_surface(base_dir, data.get("file"), scale, f"{where}.file"))
    if kind == "expression":
        return Expression(*args, need("phi"), f"{where}.phi")
    items = need("of")
    if not isinstance(items, list) or len(items) < (2 if kind != "union" else 1):
        raise SceneError(f"{where}.of: expected a list of shapes (at least two for {kind})")
    children = [read_shape(item, dim, f"{where}.of.{i}", base_dir, mesher, depth + 1) for i, item in enumerate(items)]
    return Boolean(*args, kind, children)


def checked_polygon(poly, where):
    if len(poly.edges) > MAX_POLYGON_EDGES:
        raise SceneError(f"{where}: {len(poly.edges)} edges; at most {MAX_POLYGON_EDGES} (coarsen the outline)")
    for (ax, ay), (bx, by) in poly.edges:
        if ax == bx and ay == by:
            raise SceneError(f"{where}: two consecutive vertices coincide at ({ax:g}, {ay:g})")
    crossing = first_crossing(poly.loops)
    if crossing is not None:
        raise SceneError(f"{where}: the outline crosses itself near ({crossing[0]:.4g}, {crossing[1]:.4g}); "
                         f"a polygon's loops must be simple and must not cross each other")
    area = poly.measure()
    if area is not None and area <= 0:
        raise SceneError(f"{where}: the polygon has zero area")
    return poly


def first_crossing(loops):
    """A point where two edges of the loops meet other than at their shared vertex (the loops
    cross themselves or each other, or an edge folds back on the previous one), or None."""
    start, end, ids = [], [], []
    for k, loop in enumerate(loops):
        n = len(loop)
        for i in range(n):
            start.append(loop[i - 1])
            end.append(loop[i])
            ids.append(((k, (i - 1) % n), (k, i)))
    a, b = np.array(start, float), np.array(end, float)
    d = b - a
    scale = float(np.abs(np.vstack([a, b])).max()) or 1.0
    tol = 1e-12 * scale * scale

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    for i in range(len(a)):
        j = np.arange(i + 1, len(a))
        if j.size == 0:
            break
        shared = np.array([bool(set(ids[i]) & set(ids[m])) for m in j])
        o1 = cross(d[j], a[i] - a[j])      # where edge i's ends lie against edge j
        o2 = cross(d[j], b[i] - a[j])
        o3 = cross(d[i], a[j] - a[i])      # and edge j's ends against edge i
        o4 = cross(d[i], b[j] - a[i])
        straddle = (o1 * o2 <= tol) & (o3 * o4 <= tol)
        collinear = (np.abs(o3) <= tol) & (np.abs(o4) <= tol)
        # collinear pieces meet when their projections on edge i overlap (beyond a shared end)
        t0 = ((a[j] - a[i]) @ d[i]) / (d[i] @ d[i])
        t1 = ((b[j] - a[i]) @ d[i]) / (d[i] @ d[i])
        lo, hi = np.minimum(t0, t1), np.maximum(t0, t1)
        overlap = collinear & (np.minimum(hi, 1.0) - np.maximum(lo, 0.0) > 1e-9)
        hit = np.where(shared, overlap, straddle & (~collinear | overlap))
        if hit.any():
            k = int(np.argmax(hit))
            t = o1[k] / (o1[k] - o2[k]) if abs(o1[k] - o2[k]) > tol else float(np.clip(lo[k], 0.0, 1.0))
            return tuple(float(v) for v in a[i] + t * d[i])
    return None


# ---------------------------------------------------------------- placement checks

def sample_grid(box, dim, n):
    axes = [np.linspace(lo, hi, n) for lo, hi in box]
    return np.meshgrid(*axes, indexing="ij")


def placed_measure(shape, box):
    """Exact measure of {phi < 0} inside the box when the shapes allow it, else None."""
    inner = bounded_inside(shape, box)
    if inner:
        return shape.measure()      # a rigid placement keeps it
    if isinstance(shape, HalfSpace) and shape.rotation is None:
        return clipped_half_space(shape, box)
    if isinstance(shape, Boolean) and shape.op == "difference":
        first = placed_measure(shape.children[0], box)
        holes = [c.measure() if bounded_inside(c, box) else None for c in shape.children[1:]]
        if first is None or any(h is None for h in holes) or not holes_inside(shape, box):
            return None
        return first - sum(holes)
    return None


def bounded_inside(shape, box):
    """The shape lies strictly inside the box (so the box does not clip it)."""
    bounds = shape.bounds()
    if bounds is None:
        return False
    lo, hi = bounds
    return all(b[0] < lo[i] and hi[i] < b[1] for i, b in enumerate(box))


def holes_inside(shape, box):
    """Each removed shape lies inside the first one and they do not overlap (sampled)."""
    grids = sample_grid(box, shape.dim, 201 if shape.dim == 2 else 41)
    first = shape.children[0].phi(*grids)
    holes = [c.phi(*grids) for c in shape.children[1:]]
    if any(np.any((h < 0) & (first >= 0)) for h in holes):
        return False
    return not any(np.any((holes[i] < 0) & (holes[j] < 0)) for i in range(len(holes))
                   for j in range(i + 1, len(holes)))


def clipped_half_space(shape, box):
    """Measure of a half-plane (half-space) inside the box: a polygon clip in 2D; 3D only for an
    axis-aligned normal."""
    n = np.array(shape.normal, float)
    p = np.array(shape.point, float) + (np.array(shape.translate) if shape.translate else 0)
    if shape.dim == 3:
        axes = np.nonzero(n)[0]
        if len(axes) != 1:
            return None
        a = axes[0]
        lo, hi = box[a]
        cut = min(max(p[a], lo), hi)
        length = (cut - lo) if n[a] > 0 else (hi - cut)
        others = [box[i][1] - box[i][0] for i in range(3) if i != a]
        return length * others[0] * others[1]
    (x0, x1), (y0, y1) = box
    poly = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    out = []
    for i in range(4):
        a, b = np.array(poly[i - 1]), np.array(poly[i])
        fa, fb = (a - p) @ n, (b - p) @ n
        if fa < 0:
            out.append(a)
        if (fa < 0) != (fb < 0):
            out.append(a + fa / (fa - fb) * (b - a))
    if len(out) < 3:
        return 0.0
    return 0.5 * abs(sum(out[i - 1][0] * out[i][1] - out[i][0] * out[i - 1][1] for i in range(len(out))))
