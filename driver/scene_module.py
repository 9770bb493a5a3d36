"""The scene module of a two-body run: bodies, supports, loads and probes as FreeFEM code.

The contract (every name the module defines) is docs/scene-modules.md. This
module reads the scene's bodies (a shape tree, or the legacy shapes "disk",
"ball" and "slab"), their `hold` and `load` lists and the `probe` list, checks
them against the box (a body outside the box, bodies that overlap at the start, a
probe outside its body: one SceneError each) and writes the module text.
"""

import copy
import functools
import math
import tempfile
from pathlib import Path

import numpy as np

from .errors import SceneError
from .materials import body_lame
from .schema import finite_floats
from .geometry import (MAX_POLYGON_EDGES, Boolean, Disk, HalfSpace, fmt, placed_measure, read_shape,
                             sample_grid, surfaces_in)

FACES = {"ymin": 1, "xmax": 2, "ymax": 3, "xmin": 4, "zmin": 5, "zmax": 6}
COMPONENTS = ("x", "y", "z")
DEFAULT_GMSH_S = 60.0    # limits.gmsh_s: wall-time limit of one gmsh run
MAX_MODULE_CHARS = 400_000   # the shipped scenes' modules: 2.6 kB, the cam's 17 kB


def box_of(scene, dim):
    geo = scene["geometry"]
    return [(geo[f"{c}min"], geo[f"{c}max"]) for c in COMPONENTS[:dim]]


def legacy_shape(body, dim, key):
    """The shapes of the reference scenes, written with a string shape and its keys."""
    if body["shape"] in ("disk", "ball"):
        return Disk(dim, None, None, body["centre"], body["radius"])
    normal = [0.0] * dim
    normal[-1] = 1.0
    point = [0.0] * dim
    point[-1] = body["top"]
    slab = HalfSpace(dim, None, None, point, normal)
    line = body.get("bottom_line") or []
    if not line:
        return slab
    a, b = line     # above the line y = a + b x
    return Boolean(dim, None, None, "intersection", [slab, HalfSpace(dim, None, None, [0.0, a], [b, -1.0])])


def gmsh_outline(data, base_dir, where, limits=None):
    """Closed loops of a gmsh geometry (.geo, meshed in 1D by gmsh) or of a mesh's boundary
    lines (.msh), in the plane z = 0; `size` is the mesh size given to gmsh. The file is read
    as data (driver/gmsh_input.py): it must lie in the scene's folder, and a .geo may hold
    geometry statements only."""
    from . import gmsh_input     # here: only gmsh shapes need it

    path = gmsh_input.file_inside(base_dir, data.get("file"), f"{where}.file", (".geo", ".msh"))
    size = data.get("size", 0.02)
    if isinstance(size, bool) or not isinstance(size, (int, float)) or not 0 < size < 1e6:
        raise SceneError(f"{where}.size: must be a number > 0, got {size!r}")
    if path.suffix == ".geo":
        records = gmsh_input.read_geo(path, f"{where}.file")
        gmsh_input.check_mesh_sizes(records, f"{where}.file")
        segments = 2 * gmsh_input.geo_extent(records) / size
        if segments > MAX_POLYGON_EDGES:
            raise SceneError(f"{where}.size: {size:g} gives at least {segments:.0f} edges on the outline; "
                             f"at most {MAX_POLYGON_EDGES} (a larger size)")
        seconds = (limits or {}).get("gmsh_s", DEFAULT_GMSH_S)
        with tempfile.TemporaryDirectory(prefix="fdcontact-outline-") as tmp:
            out = gmsh_input.mesh_geo(records, 1, size, f"{where}.file", Path(tmp) / "outline.msh", seconds)
            mesh = gmsh_input.read_msh(out, f"{where}.file")
    else:
        mesh = gmsh_input.read_msh(path, f"{where}.file")
    lines = [c.data for c in mesh.cells if c.type == "line"]
    name = path.name
    if not lines:
        raise SceneError(f"{where}.file: {name!r} has no boundary lines")
    if not np.all(np.isfinite(mesh.points)):
        raise SceneError(f"{where}.file: {name!r} has coordinates that are not finite")
    if np.abs(mesh.points[:, 2:]).max(initial=0.0) > 1e-12:
        raise SceneError(f"{where}.file: the outline must lie in the plane z = 0")
    edges = np.vstack(lines)
    if edges.size and (edges.min() < 0 or edges.max() >= len(mesh.points)):
        raise SceneError(f"{where}.file: {name!r} has lines through points it does not define")
    return chain_loops(edges, mesh.points[:, :2], f"{where}.file")


def chain_loops(edges, points, where):
    """Order boundary edges into closed loops of points."""
    neighbours = {}
    for a, b in edges:
        if a == b:
            continue
        neighbours.setdefault(int(a), []).append(int(b))
        neighbours.setdefault(int(b), []).append(int(a))
    if any(len(n) != 2 for n in neighbours.values()):
        raise SceneError(f"{where}: the outline is not made of closed curves (a point ends or joins >2 lines)")
    loops, seen = [], set()
    for start in sorted(neighbours):
        if start in seen:
            continue
        loop, prev, cur = [start], None, start
        seen.add(start)
        while True:
            nxt = [n for n in neighbours[cur] if n != prev]
            nxt = nxt[0] if nxt else neighbours[cur][0]
            if nxt == start:
                break
            loop.append(nxt)
            seen.add(nxt)
            prev, cur = cur, nxt
        loops.append([tuple(map(float, points[i])) for i in loop])
    return loops


class Bodies:
    """The two bodies of a scene, their supports, loads, probes and exact measures."""

    def __init__(self, scene, dim, source, base_dir):
        self.dim = dim
        self.box = box_of(scene, dim)
        self.mesher = functools.partial(gmsh_outline, limits=scene.get("limits"))
        self.shapes, self.holds, self.loads = [], [], []
        for i in (1, 2):
            body = scene[f"body{i}"]
            where = f"{source}: key body{i}.shape"
            shape = (legacy_shape(body, dim, f"body{i}") if isinstance(body["shape"], str)
                     else read_shape(body["shape"], dim, where, base_dir, self.mesher))
            self.shapes.append(shape)
            for kind in ("hold", "load"):
                if not isinstance(body.get(kind, []), list):
                    raise SceneError(f"{source}: key body{i}.{kind}: expected a list of tables")
            self.holds.append([self.boundary_part(h, f"{source}: key body{i}.hold.{n}", "displacement", base_dir)
                               for n, h in enumerate(body.get("hold", []))])
            self.loads.append([self.boundary_part(h, f"{source}: key body{i}.load.{n}", "traction", base_dir)
                               for n, h in enumerate(body.get("load", []))])
        self.check_placement(source, scene["mesh"]["nx"])
        for i in (1, 2):
            for kind, parts in (("hold", self.holds[i - 1]), ("load", self.loads[i - 1])):
                for n, part in enumerate(parts):
                    if "face" in part:
                        self.check_face_reached(i, part["face"], f"{source}: key body{i}.{kind}.{n}.face")
        probes = scene.get("probe", [])
        if not isinstance(probes, list):
            raise SceneError(f"{source}: key probe: expected [[probe]] tables")
        self.probes = [self.probe(p, f"{source}: key probe.{n}") for n, p in enumerate(probes)]
        names = [p["name"] for p in self.probes]
        if len(set(names)) != len(names):
            raise SceneError(f"{source}: key probe: two probes share a name")
        self.measures = [placed_measure(s, self.box) for s in self.shapes]

    def boundary_part(self, part, where, value_key, base_dir):
        """A hold or load: on a box face or on the part of the cut boundary inside a region."""
        if not isinstance(part, dict):
            raise SceneError(f"{where}: expected a table (face = ... or region = ...)")
        if ("face" in part) == ("region" in part):
            raise SceneError(f"{where}: give either face = \"xmin\" | \"xmax\" | ... or region = {{ shape }}")
        value = part.get(value_key, [0.0] * self.dim if value_key == "displacement" else None)
        if finite_floats(value, self.dim) is None:
            raise SceneError(f"{where}.{value_key}: expected {self.dim} finite numbers, got {str(value)[:80]}")
        out = {value_key: finite_floats(value, self.dim)}
        comps = part.get("components", "".join(COMPONENTS[:self.dim]))
        if (not isinstance(comps, str) or not comps or any(c not in COMPONENTS[:self.dim] for c in comps)
                or len(set(comps)) != len(comps)):
            raise SceneError(f"{where}.components: letters among {''.join(COMPONENTS[:self.dim])}, got {comps!r}")
        if "face" in part:
            faces = [f for f, label in FACES.items() if label <= 2 * self.dim]
            if part["face"] not in faces:
                raise SceneError(f"{where}.face: must be one of {', '.join(faces)}, got {part['face']!r}")
            out["face"] = FACES[part["face"]]
            out["components"] = comps
        else:
            if comps != "".join(COMPONENTS[:self.dim]):
                raise SceneError(f"{where}.components: a cut-boundary hold holds every component")
            out["region"] = read_shape(part["region"], self.dim, f"{where}.region", base_dir, self.mesher)
        extra = set(part) - {"face", "region", value_key, "components"}
        if extra:
            raise SceneError(f"{where}: unknown key(s) {', '.join(sorted(extra))}")
        return out

    def probe(self, probe, where):
        if not isinstance(probe, dict):
            raise SceneError(f"{where}: expected a table with name, point and body")
        name, point, body = probe.get("name"), probe.get("point"), probe.get("body", 1)
        if not isinstance(name, str) or not name or not all(c.isalnum() or c in "_-" for c in name) or len(name) > 40:
            raise SceneError(f"{where}.name: 1-40 letters, digits, '_' or '-', got {name!r}")
        if finite_floats(point, self.dim) is None:
            raise SceneError(f"{where}.point: expected {self.dim} finite numbers, got {str(point)[:80]}")
        point = finite_floats(point, self.dim)
        if isinstance(body, bool) or not isinstance(body, int) or body not in (1, 2):
            raise SceneError(f"{where}.body: must be 1 or 2, got {body!r}")
        if set(probe) - {"name", "point", "body"}:
            raise SceneError(f"{where}: unknown key(s) {', '.join(sorted(set(probe) - {'name', 'point', 'body'}))}")
        phi = float(self.shapes[body - 1].phi(*[np.array([float(v)]) for v in point])[0])
        if phi >= 0:
            raise SceneError(f"{where}.point: {point} is not inside body {body}")
        return {"name": name, "point": [float(v) for v in point], "body": body}

    def check_face_reached(self, i, label, where):
        """A box face that a hold or load names must meet body i (phi < 0 somewhere on it)."""
        axis, side = {1: (1, 0), 2: (0, 1), 3: (1, 1), 4: (0, 0), 5: (2, 0), 6: (2, 1)}[label]
        face_box = [(lo, hi) if k != axis else ((lo, lo) if side == 0 else (hi, hi))
                    for k, (lo, hi) in enumerate(self.box)]
        face = sample_grid(face_box, self.dim, 401 if self.dim == 2 else 81)
        if np.all(self.shapes[i - 1].phi(*face) >= 0):
            name = next(f for f, lab in FACES.items() if lab == label)
            raise SceneError(f"{where}: body {i} does not reach box face {name} (a face hold or load acts on "
                             f"the part of the face inside the body; use a region for a cut boundary)")

    def check_placement(self, source, nx):
        """Each body inside the box and not filling it, the two apart, on a grid of samples of
        the box; a bounded body between the samples is sampled on its own box instead."""
        n = 401 if self.dim == 2 else 61
        grids = [sample_grid(self.box, self.dim, n)]
        size = max(hi - lo for lo, hi in self.box)
        for i, phi in enumerate([s.phi(*grids[0]) for s in self.shapes], start=1):
            if not np.all(np.isfinite(phi)):
                raise SceneError(f"{source}: key body{i}.shape: the level set is not finite everywhere in the box")
            if np.count_nonzero(phi < 0) < 4:
                grids.append(self.small_body_grid(i, source, n, nx))
            if np.count_nonzero(phi >= 0) == 0:
                raise SceneError(f"{source}: key body{i}.shape: the body fills the whole box")
        for grid in grids:
            both = np.maximum(self.shapes[0].phi(*grid), self.shapes[1].phi(*grid))
            k = int(np.argmin(both))
            if both.flat[k] < -1e-9 * size:
                where = ", ".join(f"{g.flat[k]:.4g}" for g in grid)
                raise SceneError(f"{source}: key body1.shape: the bodies overlap at the start "
                                 f"(both contain ({where}), depth {-both.flat[k]:.3g})")

    def small_body_grid(self, i, source, n, nx):
        """Body i holds fewer than 4 samples of the box's grid: it misses the box, or it is a
        bounded shape smaller than the grid's step. Then it must span at least the mesh size h
        (box width / nx; a smaller body holds no mesh vertex and the mesh cannot represent it)
        and its samples come from a grid on the part of its bounding box inside the box."""
        where = f"{source}: key body{i}.shape"
        step = max((hi - lo) / (n - 1) for lo, hi in self.box)
        bounds = self.shapes[i - 1].bounds()
        if bounds is None:
            raise SceneError(f"{where}: the body misses the box (no sample of a grid of step {step:.3g} inside "
                             f"{self.box})")
        lo = [max(l, b[0]) for l, b in zip(bounds[0], self.box)]
        hi = [min(h, b[1]) for h, b in zip(bounds[1], self.box)]
        if any(h <= l for l, h in zip(lo, hi)):
            raise SceneError(f"{where}: the body misses the box (no part of it inside {self.box})")
        width = self.box[0][1] - self.box[0][0]
        span, mesh_h = min(h - l for l, h in zip(lo, hi)), width / nx
        if span < mesh_h:
            raise SceneError(f"{where}: the body spans {span:.3g} inside the box, less than the mesh size "
                             f"h = {mesh_h:.3g} (box width / mesh.nx = {nx}): the mesh cannot represent it; "
                             f"mesh.nx must exceed {math.ceil(width / span)}")
        grid = sample_grid(list(zip(lo, hi)), self.dim, 41 if self.dim == 2 else 21)
        if np.count_nonzero(self.shapes[i - 1].phi(*grid) < 0) < 4:
            raise SceneError(f"{where}: the body misses the box (no sample inside {self.box})")
        return grid

    # ------------------------------------------------------------ module text

    def module_text(self, title):
        d = self.dim
        guard = "fd2dSceneIncluded" if d == 2 else "fd3dSceneIncluded"
        point = "px, py" if d == 2 else "px, py, pz"
        coords = point.split(", ")
        lines = [f"IFMACRO(!{guard})", f"macro {guard}()1 // included once",
                 f"// Scene module ({title}), written by the driver: docs/scene-modules.md lists every name.",
                 "// Generated from the scene file; edit the scene, not this file."]
        surfaces = self.surfaces()
        if surfaces:
            lines.append('include "freefem/lib/fd3d/surface.idp"   // surfaceFromTable: the surface shapes\' tables')
        for surface in surfaces.values():
            lines.append(f'int {surface.variable} = surfaceFromTable("{surface.table_name}");   // beside this module')
        for i, shape in enumerate(self.shapes, start=1):
            lines.append(f"macro phi{i}At({point}) {shape.code(*coords)} //")
        for i in (1, 2):
            lines += self.face_arrays(i)
            lines += self.cut_macros(i, "hold", "displacement", "U", point, coords)
            lines += self.cut_macros(i, "load", "traction", "T", point, coords)
        lines.append(f"int probeCount = {len(self.probes)};")
        for c in COMPONENTS[:d]:
            values = ", ".join(fmt(p["point"][COMPONENTS.index(c)]) for p in self.probes) or "0."
            lines.append(f"real[int] probe{c.upper()} = [{values}];")
        lines.append(f"real[int] probeBody = [{', '.join(str(p['body']) for p in self.probes) or '0'}];")
        lines.append(f"string[int] probeName({max(len(self.probes), 1)});")
        for n, p in enumerate(self.probes):
            lines.append(f"probeName[{n}] = \"{p['name']}\";")
        for i, m in enumerate(self.measures, start=1):
            lines.append(f"real exactMeasure{i} = {fmt(m) if m is not None else '-1.'};")
        lines.append("ENDIFMACRO")
        return "\n".join(lines) + "\n"

    def surfaces(self):
        """The surface shapes of the bodies and of their hold and load regions, by table name."""
        trees = self.shapes + [p["region"] for parts in self.holds + self.loads for p in parts if "region" in p]
        return {s.table_name: s for tree in trees for s in surfaces_in(tree)}

    def face_arrays(self, i):
        d = self.dim
        held = {c: [0.0] * 7 for c in COMPONENTS[:d]}
        value = {c: [0.0] * 7 for c in COMPONENTS[:d]}
        loaded, traction = [0.0] * 7, {c: [0.0] * 7 for c in COMPONENTS[:d]}
        for hold in self.holds[i - 1]:
            if "face" in hold:
                for c in hold["components"]:
                    held[c][hold["face"]] = 1.0
                    value[c][hold["face"]] = hold["displacement"][COMPONENTS.index(c)]
        for load in self.loads[i - 1]:
            if "face" in load:
                loaded[load["face"]] = 1.0
                for n, c in enumerate(COMPONENTS[:d]):
                    traction[c][load["face"]] += load["traction"][n]

        def arr(name, values):
            return f"real[int] {name} = [{', '.join(fmt(v) for v in values)}];"

        out = [arr(f"holdFace{i}{c.upper()}", held[c]) for c in COMPONENTS[:d]]
        out += [arr(f"holdFace{i}U{c}", value[c]) for c in COMPONENTS[:d]]
        out.append(arr(f"loadFace{i}", loaded))
        out += [arr(f"loadFace{i}T{c}", traction[c]) for c in COMPONENTS[:d]]
        return out

    def cut_macros(self, i, kind, value_key, letter, point, coords):
        parts = [p for p in (self.holds if kind == "hold" else self.loads)[i - 1] if "region" in p]
        inside = [f"({p['region'].code(*coords)} < 0)" for p in parts]
        out = [f"int {kind}CutAny{i} = {1 if parts else 0};",
               f"macro {kind}Cut{i}({point}) {' || '.join(inside) if inside else '0'} //"]
        for n, c in enumerate(COMPONENTS[:self.dim]):
            expr = "0."
            for p, test in reversed(list(zip(parts, inside))):
                expr = f"({test} ? {fmt(p[value_key][n])} : {expr})"
            out.append(f"macro {kind}Cut{i}{letter}{c}({point}) {expr} //")
        if kind == "hold":      # which hold a point belongs to: its reaction (results.json reactions.by_support)
            region = "0"
            for r, test in reversed(list(enumerate(inside, start=1))):
                region = f"({test} ? {r} : {region})"
            out += [f"int holdCutCount{i} = {len(parts)};", f"macro holdCut{i}Region({point}) {region} //"]
        return out

    # ------------------------------------------------------------ facts for the driver

    def floating(self, i):
        """No support of body i holds every component."""
        full = "".join(COMPONENTS[:self.dim])
        return not any("region" in h or h["components"] == full for h in self.holds[i - 1])


def fill_legacy(scene, source, shapes, defaults):
    """The legacy shapes (shapes: body -> name, e.g. "disk", "slab") take their keys'
    defaults; those keys are refused beside a shape table. Then the legacy slab's
    support and, for a legacy body 1 without probes, a probe "centre" at its centre."""
    for key, keys in defaults.items():
        body = scene[key]
        legacy = isinstance(body["shape"], str)
        if legacy and body["shape"] != shapes[key]:
            raise SceneError(f"{source}: key '{key}.shape': a name must be {shapes[key]!r} (the legacy "
                             f"shape); other shapes are tables {{ type = \"{body['shape']}\", ... }}")
        for name, default in keys.items():
            if body[name] is None:
                body[name] = default
            elif not legacy:
                raise SceneError(f"{source}: key '{key}.{name}': belongs to the legacy shape "
                                 f"{shapes[key]!r}, not to a shape table")


def check_two_bodies(tables, source, base_dir, dim, legacy_shapes, legacy_keys):
    """The checks the 2D and 3D fictitious-domain scenes share: a box of positive size,
    each body's Lame coefficients, the legacy keys filled, the legacy slab's top inside
    the box (along its last axis), the legacy supports and probe, the bodies (their files
    read from base_dir); adaptation needs the estimators. Returns the tables filled in (a
    copy: `tables` is left as it was) and the derived values: bodies, lame."""
    scene = copy.deepcopy(tables)
    geo = scene["geometry"]
    axes = "xyz"[:dim]
    if not all(geo[f"{a}max"] > geo[f"{a}min"] for a in axes):
        raise SceneError(f"{source}: key 'geometry': the box is empty (need max > min on every axis)")
    lame = tuple(body_lame(scene[key], source, key) for key in ("body1", "body2"))
    fill_legacy(scene, source, legacy_shapes, legacy_keys)
    slab, vertical = scene["body2"], axes[-1]
    if isinstance(slab["shape"], str) and not geo[f"{vertical}min"] < slab["top"] < geo[f"{vertical}max"]:
        raise SceneError(f"{source}: key 'body2.top': the slab top {slab['top']} misses the box "
                         f"({geo[vertical + 'min']}, {geo[vertical + 'max']})")
    legacy_supports(scene, dim)
    legacy_probe(scene)
    bodies = Bodies(scene, dim, source, base_dir)
    try:
        text = bodies.module_text(scene["scene"]["name"])
    except SceneError as exc:
        raise SceneError(f"{source}: key body1/body2: {exc}") from None
    if len(text) > MAX_MODULE_CHARS:
        raise SceneError(f"{source}: the scene module would be {len(text):,} characters; at most "
                         f"{MAX_MODULE_CHARS:,} (use fewer or simpler shapes, regions and polygons)")
    if scene["adapt"]["steps"] > 0 and not scene["output"]["estimators"]:
        raise SceneError(f"{source}: key 'adapt.steps': adaptation (adapt.steps > 0) needs output.estimators = true")
    return scene, {"bodies": bodies, "lame": lame}


def legacy_probe(scene):
    if isinstance(scene["body1"]["shape"], str) and not scene["probe"]:
        scene["probe"] = [{"name": "centre", "point": list(scene["body1"]["centre"]), "body": 1}]


def scene_module(scene):
    """Text of a checked scene's module (the runner writes it as RUN/scene.idp)."""
    return scene.bodies.module_text(scene["scene"]["name"])


def scene_files(scene):
    """The files the module reads beside it (the runner writes them into the run folder):
    the surface shapes' tables, by name."""
    return {name: surface.table for name, surface in scene.bodies.surfaces().items()}


def legacy_supports(scene, dim):
    """Supports of the legacy slab: strongly on the box bottom, or Nitsche on its bottom line."""
    body2 = scene["body2"]
    if not isinstance(body2["shape"], str) or body2.get("hold"):
        return
    line = body2.get("bottom_line") or []
    if dim == 2 and line:
        a, b = line
        s = math.sqrt(1 + b * b)
        # the slab's bottom piece: nearer the line y = a + b x than the top (as a half-plane)
        normal = [-b / s, 1 + 1 / s]
        y0 = (body2["top"] + a / s) / (1 + 1 / s)
        body2["hold"] = [{"region": {"type": "half_plane", "point": [0.0, y0], "normal": normal},
                          "displacement": [0.0, 0.0]}]
    else:
        body2["hold"] = [{"face": "ymin" if dim == 2 else "zmin", "displacement": [0.0] * dim}]


def support_lines(results):
    """Summary lines: the force of each support on its body (results.json reactions.by_support)."""
    by_support = results.get("reactions", {}).get("by_support", {})
    return [f"support {name}: reaction ({', '.join(f'{v:.4g}' for v in force)})"
            for name, force in by_support.items()]


def summary_head(results):
    """The first lines of a two-body run's summary (after the scene's): the recovered peak
    pressure and how many elements the contact zone spans, and a warning when that is
    below what the recovered pressure needs."""
    contact = results["contact"]
    lines = [contact_headline(contact)]
    if contact.get("active_extent") and not contact.get("zone_resolved", 1):
        levers = "mesh.nx, mesh.grade_h, adapt.steps" if results.get("dim") == 3 else "mesh.nx, adapt.steps"
        lines.append(f"WARNING: the contact zone is not resolved: its half-width spans "
                     f"{contact['zone_elements']:.2g} elements, the recovered pressure needs "
                     f"{contact['zone_elements_needed']:g} (refine near the contact: {levers}); "
                     f"forces and displacements are not affected")
    return lines


def summary_lines(results):
    """The rest of a two-body run's summary (2D or 3D): the gates, estimators, adaptation
    (and why it stopped), bodies, probes, supports, the contact's force and balance, cut
    statistics."""
    contact, cut, dim = results["contact"], results["cut"], results["dim"]
    measure, active = ("area", "length") if dim == 2 else ("volume", "area")
    lines = gate_lines(results)
    est = results.get("estimator")
    if est:
        lines.append("estimator: eta {eta:.4g} (eta1 {eta1:.3g}, eta2 {eta2:.3g}, eta3 {eta3:.3g}, eta4 {eta4:.3g}, "
                     "eta5 {eta5:.3g}), zeta {zeta:.3g}".format(**est))
    lines += adaptation_lines(results, measure)
    force = contact["force_on_body1"]
    return lines + [
        f"bodies: {results['dofs_body1']} + {results['dofs_body2']} DOFs on the cut spaces, "
        f"{measure}s {results['measures']['body1']:.6g} and {results['measures']['body2']:.6g}",
    ] + [f"probe {name}: displacement ({', '.join(f'{v:.6g}' for v in u)})"
         for name, u in results.get("probes", {}).items()] + support_lines(results) + [
        f"contact: active {active} {contact['active_measure']:.4g} of {contact['boundary_measure']:.4g}, "
        f"force on body 1 ({', '.join(f'{v:.6g}' for v in force)}), "
        f"balance error {contact['force_balance_error']:.1e}, raw pressure peak {contact['max_pressure']:.4g}",
        f"cut elements: min ratio {cut['min_ratio_body1']:.2e} (body 1), {cut['min_ratio_body2']:.2e} (body 2); "
        f"stabilization {cut['stabilization']}: cases a/b/c = {cut['case_a']}/{cut['case_b']}/{cut['case_c']}, "
        f"sliver elements dropped {cut.get('dropped_body1', 0)} + {cut.get('dropped_body2', 0)}",
    ]


def contact_headline(contact):
    """The summary's first line: the recovered peak pressure (the raw multiplier's scatters,
    docs/outputs.md) and the contact zone's size in elements."""
    if not contact.get("active_extent"):
        return "contact: no active contact point"
    return (f"contact: peak pressure {contact['max_pressure_recovered']:.4g} (recovered; raw "
            f"{contact['max_pressure']:.4g}), zone half-width {contact['zone_half_width']:.4g} = "
            f"{contact['zone_elements']:.2g} elements of size {contact['zone_element_size']:.3g}")


def adaptation_lines(results, measure):
    """The adaptive loop: its solves, DOFs, eta and body 1's measure, and why it stopped
    (results.json adapt.stop; the DOF budget by name)."""
    steps, adapt = results.get("steps", {}), results.get("adapt", {})
    if len(steps.get("dofs", [])) < 2 and adapt.get("steps_requested", 0) == 0:
        return []
    why = {"steps": "after every step asked",
           "eta_target": "at the estimator target adapt.eta_target",
           "dof_budget": f"at its DOF budget (adapt.max_dofs = {adapt.get('max_dofs', 0):g}: the next mesh "
                         f"would pass it) after {adapt.get('steps_done', 0):g} of "
                         f"{adapt.get('steps_requested', 0):g} steps"}.get(adapt.get("stop"), "")
    remesher = adapt.get("remesher", "").split(":")[0]
    return [f"adaptation ({remesher}): {len(steps['dofs'])} solves, DOFs "
            f"{int(steps['dofs'][0])} -> {int(steps['dofs'][-1])}, eta {steps['eta'][0]:.4g} -> "
            f"{steps['eta'][-1]:.4g}, body 1 {measure} {steps['measure_body1'][0]:.6f} -> "
            f"{steps['measure_body1'][-1]:.6f}" + (f"; stopped {why}" if why else "")]


def gate_lines(results):
    """Summary lines of a run kept past its gates (results.json plausibility and balance,
    freefem/lib/core/gates.idp): what the scene's allow flag let through."""
    kept = [("plausibility", "implausible", "IMPLAUSIBLE (kept by solver.allow_implausible)"),
            ("balance", "unbalanced", "UNBALANCED (kept by solver.allow_unbalanced)")]
    return [f"{label}: {results[key]['message']}" for key, flag, label in kept
            if results.get(key, {}).get(flag)]
