"""Scenes for freefem/fd_contact_3d.edp: two bodies on one background mesh of a box in 3D.

Each body is a shape tree (driver/geometry.py: ball, ellipsoid, box with rounded
edges, cylinder, half-space, an expression, and their unions, intersections and
differences, placed by translate and rotate) with supports (`hold`, on box faces
strongly or on cut parts by Nitsche) and loads (`load`, tractions; a body force),
written as the run's scene module (driver/scene_module.py, docs/scene-modules.md).
The legacy shapes "ball" (centre, radius) and "slab" (top, held on the box bottom)
of the reference scene still read as before. A floating body 1 (no support
holding every component) has its rigid motions held by the mass term and by a
penalty on u1_x, u1_y at two points A, B on a vertical line and on u1_y at a
third point C off it (z translation is carried by the contact).

Rules across keys (check below): the box is not empty; each body meets the box and
they do not overlap at the start; a probe lies in its body; A, B and C lie inside
body 1, A and B on one vertical line at different heights, C off it in x; each
body gives lambda and mu or E and nu (not both); adapt.steps > 0 needs
output.estimators; adapt.switch starts with r, holds a and no p.
"""

import numpy as np

from .errors import SceneError
from .fd2d import body_schema
from .scene_module import check_two_bodies, summary_head, summary_lines  # noqa: F401  (the CLI's)
from .scene_module import scene_files, scene_module  # noqa: F401  (the runner calls both)
from .header import SCENE_HEADER
from .schema import (ADAPT_SCHEMA, Field, FreeFemFlags, Range, at_least, between, positive,
                           put_declared, two_body_method_schema, two_body_solver_schema)

STABILIZATIONS = ("auto", "none", "neighbour", "ghost")


SCHEMA = {
    "geometry": {
        "xmin": Field("float", flag="xmin", default=-0.5, unit="length", doc="background box, x from"),
        "xmax": Field("float", flag="xmax", default=0.5, unit="length", doc="background box, x to (> xmin)"),
        "ymin": Field("float", flag="ymin", default=-0.5, unit="length", doc="background box, y from"),
        "ymax": Field("float", flag="ymax", default=0.5, unit="length", doc="background box, y to (> ymin)"),
        "zmin": Field("float", flag="zmin", default=-0.5, unit="length",
                      doc="background box, bottom (the slab is clamped here)"),
        "zmax": Field("float", flag="zmax", default=0.5, unit="length", doc="background box, top (> zmin)"),
    },
    "mesh": {
        "nx": Field("int", flag="nx", default=10, check=between(2, 150),
                    doc="cells along x (h = width/nx); along y and z as many as keep them cubic (at most 150: a "
                        "P1 run at nx = 48 takes about 2 GiB)"),
        "grade_h": Field("float", flag="grade_h", default=0.0, check=at_least(0.0), unit="length",
                         doc="0: uniform; else tetgen refines toward the contact point to this edge size "
                             "(mesh.grade_passes)"),
        "grade_radius": Field("float", flag="grade_radius", default=0.1, check=at_least(0.0), unit="length",
                              doc="edge size grade_h within this distance of the contact point"),
        "grade_point": Field("vector", derived="grade_x grade_y grade_z", default=None, length=3, unit="length",
                             doc="where grading refines (default: the legacy ball's contact point, else the "
                                 "first probe)"),
        "grade_slope": Field("float", flag="grade_slope", default=0.25, check=positive, unit="1",
                             doc="growth of the edge size with the distance beyond grade_radius"),
        "grade_passes": Field("int", flag="grade_passes", default=1, check=between(1, 8),
                              doc="tetgen passes of the grading, each reading the wanted size on the mesh the "
                                  "last one made (one pass reads it at the background's centroids: near the "
                                  "point the elements stay about twice grade_h); stops when a pass adds < 2 %"),
    },
    "body1": body_schema({
        "shape": Field("tree", default="ball", doc="a shape table (docs/scenes.md, 'Shapes'), or the legacy "
                                                   "name \"ball\" with the keys below"),
        "centre": Field("vector", default=None, length=3, unit="length",
                        doc="legacy ball: centre (default [0, 0, 0])"),
        "radius": Field("float", default=None, check=positive, unit="length",
                        doc="legacy ball: radius (default 0.25)"),
    }, [0.0, 0.0, -0.1], 1),
    "body2": body_schema({
        "shape": Field("tree", default="slab", doc="a shape table, or the legacy name \"slab\" (the box below "
                                                   "top, held on the box bottom)"),
        "top": Field("float", default=None, unit="length", doc="legacy slab: height of its top (default -0.25)"),
    }, [0.0, 0.0, 0.0], 2),
    "probe": Field("tree", default=[], doc="named points: [[probe]] tables with name, point = [x, y, z] and body "
                                           "(1 or 2); results.json 'probes' gives their displacement"),
    "rigid": {
        "mass_eps": Field("float", flag="mass_eps", default=1e-7, check=at_least(0.0), unit="1",
                          doc="mass term eps muStar int u1.v1 against the floating ball's rigid motions "
                              "(relative to the shear modulus muStar, see method.gamma_scaling)"),
        "fix_xy_points": Field("vector", derived="pins fix_ax fix_ay fix_az fix_bx fix_by fix_bz", default=None,
                               unit="length",
                               doc="pins of a floating body 1: u1_x = u1_y = 0 at A and B (xA, yA, zA, xB, yB, "
                                   "zB), inside it, on one vertical line; [] none (default: from the body)"),
        "fix_y_point": Field("vector", flag=("fix_cx", "fix_cy", "fix_cz"), default=None, length=3, unit="length",
                             doc="u1_y = 0 at C (rotation about z), inside the ball, off the line AB in x"),
    },
    "method": dict(two_body_method_schema(1), **{
        "geometry": Field("str", flag="geometry", default="curved", choices=("p1", "curved"),
                          doc="cut geometry: curved integrates on the exact level set of the shapes "
                              "(docs/curved-geometry.md: compiled cells, each volume rule checked; the load is "
                              "then the exact volume's, docs/hertz-3d.md); p1 on the P1 interpolant of each level "
                              "set (polyhedra, volume error O(h^2)), which the 3D studies measured on it pin"),
        "stabilization": Field("str", flag="stabilization", default="auto", choices=STABILIZATIONS,
                               doc="auto: neighbour for theta > 0 (coercivity on cut elements), none otherwise; "
                                   "neighbour: stress of the best-cut neighbour (R_rho); ghost: ghost penalty on the "
                                   "faces of the cut elements"),
        "gamma_scaling": Field("str", flag="gamma_scaling", default="shear", choices=("shear", "none"),
                               doc="shear: gamma = gamma0 h_K / muStar, muStar = 2 mu1 mu2/(mu1 + mu2) (gamma0 "
                                   "dimensionless); none: gamma = gamma0 h_K (gamma0 in 1/stress)"),
    }),
    "solver": two_body_solver_schema("ball", Field(
        "int", flag="contact_qp", default=0, choices=(0, 1, 3, 6),
        doc="points per interface triangle (0: 3 for P1, 6 for P2)")),
    "adapt": dict(ADAPT_SCHEMA, growth=Field(
        "float", flag="adapt_growth", default=2.0, check=Range(1.0, 16.0, lo_open=True), unit="1",
        doc="wanted element-count growth per step (> 1: tetgen only refines)"), switch=Field(
        "str", flag="adapt_switch", default="rqaAQ",
        doc="tetgen switches of tetgreconstruction (r refine, q quality, a volume bounds); must start with r, "
            "hold a and no p; steps refine by tetgen, max_coarsen is unused (tetgen never coarsens)")),
    "output": {
        "vtu": Field("bool", flag="vtu", default=True,
                     doc="body VTUs and estimators.vtu (P0 eta fields on the background mesh)"),
        "estimators": Field("bool", flag="estimators", default=True,
                            doc="residual estimators eta1..eta5 (needed by adapt.steps > 0)"),
        "csv": Field("bool", flag="csv", default=True, doc="contact_pressure.csv and centre_cut.csv"),
        "save_solution": Field("bool", flag="save", default=False,
                               doc="write meshes and DOF arrays (a reference)"),
    },
}


LEGACY_KEYS = {"body1": {"centre": [0.0, 0.0, 0.0], "radius": 0.25}, "body2": {"top": -0.25}}
LEGACY_SHAPES = {"body1": "ball", "body2": "slab"}


def default_fix_points(bodies):
    """A, B on the vertical line through body 1's deepest sampled point, C beside it."""
    shape = bodies.shapes[0]
    grids = [np.linspace(lo, hi, 41) for lo, hi in bodies.box]
    pts = np.meshgrid(*grids, indexing="ij")
    phi = shape.phi(*pts)
    k = int(np.argmin(phi))
    c = [float(g.flat[k]) for g in pts]
    d = 0.4 * float(-phi.flat[k])
    return c + [c[0], c[1], c[2] + d], [c[0] + d, c[1], c[2]]


def check(tables, source, base_dir):
    """Cross-field rules the schema cannot express: (the tables filled in, the derived values);
    `tables` is left as it was."""
    scene, derived = check_two_bodies(tables, source, base_dir, 3, LEGACY_SHAPES, LEGACY_KEYS)
    bodies = derived["bodies"]
    if not scene["adapt"]["switch"].startswith("r") or "a" not in scene["adapt"]["switch"] or "p" in scene["adapt"]["switch"]:
        raise SceneError(f"{source}: key 'adapt.switch': tetgreconstruction needs 'r' first, 'a', and no 'p'")
    rigid = scene["rigid"]
    if rigid["fix_xy_points"] is None or rigid["fix_y_point"] is None:
        if isinstance(scene["body1"]["shape"], str):
            ab, c = [0.0, 0.0, 0.0, 0.0, 0.0, 0.1], [0.1, 0.0, 0.0]
        else:
            ab, c = default_fix_points(bodies)
        rigid["fix_xy_points"] = ab if rigid["fix_xy_points"] is None else rigid["fix_xy_points"]
        rigid["fix_y_point"] = c if rigid["fix_y_point"] is None else rigid["fix_y_point"]
    if len(rigid["fix_xy_points"]) not in (0, 6):
        raise SceneError(f"{source}: key 'rigid.fix_xy_points': expected [xA, yA, zA, xB, yB, zB] or [] (no pins)")
    if not bodies.floating(1) or not rigid["fix_xy_points"]:
        return scene, derived
    a, b = rigid["fix_xy_points"][:3], rigid["fix_xy_points"][3:]
    for name, point in (("fix_xy_points", a), ("fix_xy_points", b), ("fix_y_point", rigid["fix_y_point"])):
        if bodies.shapes[0].phi(*[np.array([v]) for v in point])[0] >= 0:
            raise SceneError(f"{source}: key 'rigid.{name}': {point} is not inside body 1")
    if abs(a[0] - b[0]) > 1e-12 or abs(a[1] - b[1]) > 1e-12 or a[2] == b[2]:
        raise SceneError(f"{source}: key 'rigid.fix_xy_points': A and B must lie on one vertical line, "
                         f"at different heights")
    if abs(rigid["fix_y_point"][0] - a[0]) < 1e-12:
        raise SceneError(f"{source}: key 'rigid.fix_y_point': C must lie off the vertical line "
                         f"through A and B in x (it fixes the rotation about z)")
    return scene, derived


def grade_point(scene):
    """Where grading refines: mesh.grade_point, else the legacy ball's lowest point on the
    slab top, else the first probe."""
    if scene["mesh"]["grade_point"]:
        return scene["mesh"]["grade_point"]
    body1, body2 = scene["body1"], scene["body2"]
    if isinstance(body1["shape"], str) and isinstance(body2["shape"], str):
        return [body1["centre"][0], body1["centre"][1], body2["top"]]
    probes = scene["probe"]
    return probes[0]["point"] if probes else [0.0, 0.0, 0.0]


def freefem_args(scene, mesh_file=""):
    """The script's flags: every key the schema declares, then the values derived here."""
    args = FreeFemFlags([f"-Ddegree={scene['method']['degree']}"])
    put_declared(args, scene, dict(scene=SCENE_HEADER, **SCHEMA))
    if scene["mesh"]["grade_h"] > 0:
        for axis, value in zip("xyz", grade_point(scene)):
            args.put(f"grade_{axis}", value)
    for i, (lam, mu) in enumerate(scene.lame, 1):
        args.put(f"lambda{i}", lam)
        args.put(f"mu{i}", mu)
    pins = scene["rigid"]["fix_xy_points"]
    args.put("pins", int(bool(pins)))       # they act only on a floating body 1
    for key, value in zip(("fix_ax", "fix_ay", "fix_az", "fix_bx", "fix_by", "fix_bz"), pins):
        args.put(key, value)
    return args


def prepare_mesh(scene, workdir, run_command):
    return ""      # the background mesh is a FreeFEM cube
