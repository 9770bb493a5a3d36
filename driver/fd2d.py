"""Scenes for freefem/fd_contact_2d.edp: two bodies on one background mesh (fictitious domain).

Each body is a shape tree (driver/geometry.py: disk, ellipse, box with rounded
corners, half-plane, polygon, a gmsh outline, an expression, and their unions,
intersections and differences, placed by translate and rotate) with supports
(`hold`: a displacement on a box face, strongly, or on the part of the cut boundary
inside a region, by Nitsche) and loads (`load`: a traction likewise; a body force).
The driver writes them as the run's scene module (driver/scene_module.py,
docs/scene-modules.md). The legacy shapes "disk" (centre, radius) and "slab" (top,
bottom_line) of the reference scenes still read as before.

Rules across keys (check below): the box is not empty; each body meets the box and
they do not overlap at the start; a probe lies in its body; the pins
(rigid.fix_x_points) lie inside body 1 and act only when body 1 is floating (no
support holding every component); each body gives lambda and mu or E and nu (not
both); adapt.steps > 0 needs output.estimators; a Nitsche hold needs
gamma_scaling shear or none.
"""

import numpy as np

from .errors import SceneError
from .scene_module import check_two_bodies, summary_head, summary_lines  # noqa: F401  (the CLI's)
from .scene_module import scene_module  # noqa: F401  (the runner calls module.scene_module)
from .header import SCENE_HEADER
from .schema import (ADAPT_SCHEMA, Field, FreeFemFlags, at_least, between, open_interval, positive,
                           put_declared, two_body_method_schema, two_body_solver_schema)

STABILIZATIONS = ("auto", "none", "neighbour", "ghost")
GAMMA_SCALINGS = ("shear", "none", "body1", "mean_compliance")


SHAPE_DOC = ("a shape table {{ type = ..., ... }} (docs/scenes.md, 'Shapes'), or the legacy name {legacy} "
             "with the keys below")
HOLD_DOC = ("supports: [[bodyN.hold]] tables, each on a box face (face = \"xmin\" ... ; displacement, "
            "components) held strongly, or on the cut boundary inside a region (region = {{ shape }}; "
            "displacement) held by Nitsche")
LOAD_DOC = ("tractions: [[bodyN.load]] tables, each on a box face (face = ...) or on the cut boundary inside "
            "a region (region = {{ shape }}), with traction = [...] (force/area)")


def body_schema(shape_fields, force, n):
    """Body n's fields: its shape, supports, loads, Lame (or E, nu) and a volume force."""
    lame = f"lambda{n} mu{n}"
    force_flags = tuple(f"f{n}{axis}" for axis in "xyz"[:len(force)])
    return dict(shape_fields, **{
        "hold": Field("tree", default=[], doc=HOLD_DOC),
        "load": Field("tree", default=[], doc=LOAD_DOC),
        "lambda": Field("float", derived=lame, default=None, unit="stress",
                        doc="first Lame coefficient (give lambda and mu, or E and nu); lambda + mu > 0"),
        "mu": Field("float", derived=lame, default=None, check=positive, unit="stress",
                    doc="shear modulus (with lambda)"),
        "E": Field("float", derived=lame, default=None, check=positive, unit="stress",
                   doc="Young's modulus (with nu)"),
        "nu": Field("float", derived=lame, default=None, check=open_interval(-1.0, 0.5), unit="1",
                    doc="Poisson's ratio (with E; plane strain in 2D)"),
        "body_force": Field("vector", flag=force_flags, default=force, length=len(force), unit="force/volume",
                            doc="volume force on the body"),
    })


SCHEMA = {
    "geometry": {
        "xmin": Field("float", flag="xmin", default=-0.5, unit="length", doc="background box, left side"),
        "xmax": Field("float", flag="xmax", default=0.5, unit="length", doc="background box, right side (> xmin)"),
        "ymin": Field("float", flag="ymin", default=-0.5, unit="length",
                      doc="background box, bottom (the slab is clamped here)"),
        "ymax": Field("float", flag="ymax", default=0.5, unit="length", doc="background box, top (> ymin)"),
    },
    "mesh": {
        "nx": Field("int", flag="nx", default=80, check=between(2, 4000),
                    doc="elements along x (h = width/nx); along y as many as keep them as tall as wide (at most "
                        "4000: about 32 nx^2 background DOFs)"),
    },
    "body1": body_schema({
        "shape": Field("tree", default="disk", doc=SHAPE_DOC.format(legacy='"disk"')),
        "centre": Field("vector", default=None, length=2, unit="length",
                        doc="legacy disk: centre (default [0, 0])"),
        "radius": Field("float", default=None, check=positive, unit="length",
                        doc="legacy disk: radius (default 0.25)"),
    }, [0.0, -0.1], 1),
    "body2": body_schema({
        "shape": Field("tree", default="slab", doc=SHAPE_DOC.format(legacy='"slab" (the box below top)')),
        "top": Field("float", default=None, unit="length", doc="legacy slab: height of its top (default -0.25)"),
        "bottom_line": Field("vector", default=None, unit="length, 1",
                             doc="legacy slab: [a, b]: held by Nitsche on y = a + b x, crossing the box below "
                                 "top; absent: held strongly on the box bottom"),
    }, [0.0, 0.0], 2),
    "probe": Field("tree", default=[], doc="named points: [[probe]] tables with name, point = [x, y] and body "
                                           "(1 or 2); results.json 'probes' gives their displacement"),
    "rigid": {
        "mass_eps": Field("float", flag="mass_eps", default=1e-7, check=at_least(0.0), unit="1",
                          doc="mass term eps muStar int u.v against the rigid motions of a floating body "
                              "(relative to the shear modulus muStar, see method.gamma_scaling)"),
        "fix_x_points": Field("vector", derived="pins fix_ax fix_ay fix_bx fix_by", default=None, unit="length",
                              doc="pins of a floating body 1: u1_x = 0 at the nodes nearest to two points "
                                  "[x1, y1, x2, y2] inside it, at different heights (they hold x translation and "
                                  "rotation); [] none (default: [0, 0, 0, 0.1] for the legacy disk, none "
                                  "otherwise)"),
    },
    "method": dict(two_body_method_schema(2), **{
        "geometry": Field("str", flag="geometry", default="curved", choices=("p1", "curved"),
                          doc="cut geometry: curved integrates on the exact level set of the shapes "
                              "(docs/curved-geometry.md); p1 on the P1 interpolant of each level set (a polygon, "
                              "area error O(h^2), which limits P2)"),
        "stabilization": Field("str", flag="stabilization", default="auto", choices=STABILIZATIONS,
                               doc="auto: ghost for theta > 0 (coercivity on cut elements), none otherwise; "
                                   "neighbour: stress of the best-cut neighbour (R_rho); ghost: ghost penalty"),
        "gamma_scaling": Field("str", flag="gamma_scaling", default="shear", choices=GAMMA_SCALINGS,
                               doc="shear: gamma = gamma0 h_K / muStar, muStar = 2 mu1 mu2/(mu1 + mu2) (gamma0 "
                                   "dimensionless); none: gamma = gamma0 h_K (gamma0 in 1/stress); body1: "
                                   "gamma = gamma0 h_K / E1 (Young modulus of the disk, whose sigma_n enters the "
                                   "Nitsche terms); mean_compliance: gamma = gamma0 h_K (1/E1 + 1/E2)/2"),
    }),
    "solver": dict(two_body_solver_schema("disk", Field(
        "int", flag="contact_qp", default=3, choices=(1, 2, 3, 4), doc="Gauss points per cut segment")),
        time_final_solve=Field("bool", flag="time_final_solve", default=False,
                               doc="benchmarks: time one extra factorization and solve of the final system")),
    "adapt": dict(ADAPT_SCHEMA, warm_start=Field(
        "int", flag="adapt_warm_start", default=1, choices=(0, 1, 2),
        doc="Newton start after adaptation: 0 default, 1 previous active measure, 2 previous solution")),
    "output": {
        "vtu": Field("bool", flag="vtu", default=True, doc="write fields.vtu"),
        "pressure_csv": Field("bool", flag="csv", default=True, doc="write contact_pressure.csv"),
        "estimators": Field("bool", flag="estimators", default=True,
                            doc="residual estimators eta_1..eta_5 (needed by adapt.steps > 0)"),
        "save_solution": Field("bool", flag="save", default=False,
                               doc="write meshes and DOF arrays (a reference; every step when adapting)"),
        "export_matrix": Field("bool", flag="export_matrix", default=False,
                               doc="write the last Newton matrix on the free DOFs (newton_matrix.mtx, MatrixMarket)"),
    },
}


LEGACY_KEYS = {"body1": {"centre": [0.0, 0.0], "radius": 0.25}, "body2": {"top": -0.25, "bottom_line": []}}
LEGACY_SHAPES = {"body1": "disk", "body2": "slab"}


def check(tables, source, base_dir):
    """Cross-field rules the schema cannot express: (the tables filled in, the derived values);
    `tables` is left as it was."""
    scene, derived = check_two_bodies(tables, source, base_dir, 2, LEGACY_SHAPES, LEGACY_KEYS)
    bodies = derived["bodies"]
    geo, slab = scene["geometry"], scene["body2"]
    line = slab["bottom_line"]
    if isinstance(slab["shape"], str) and line:
        if len(line) != 2:
            raise SceneError(f"{source}: key 'body2.bottom_line': expected [a, b] (y = a + b x), got {line}")
        a, b = line
        ends = (a + b * geo["xmin"], a + b * geo["xmax"])
        if not all(geo["ymin"] <= y < slab["top"] for y in ends):
            raise SceneError(f"{source}: key 'body2.bottom_line': the line y = {a:g} + {b:g} x must cross "
                             f"the box between its bottom and the slab top")
    nitsche_hold = any("region" in h for holds in bodies.holds for h in holds)
    if nitsche_hold and scene["method"]["gamma_scaling"] not in ("none", "shear"):
        raise SceneError(f"{source}: key 'method.gamma_scaling': {scene['method']['gamma_scaling']!r} scales "
                         f"the contact gamma by the moduli; with a Nitsche hold (a region) use 'shear' or 'none'")
    fix = scene["rigid"]["fix_x_points"]
    if fix is None:
        fix = [0.0, 0.0, 0.0, 0.1] if isinstance(scene["body1"]["shape"], str) else []
    if fix and len(fix) != 4:
        raise SceneError(f"{source}: key 'rigid.fix_x_points': expected [x1, y1, x2, y2] or [], got {fix}")
    if fix and not bodies.floating(1):
        raise SceneError(f"{source}: key 'rigid.fix_x_points': body 1 is held by a support; pins are for a "
                         f"floating body 1 (use [])")
    for px, py in (fix[:2], fix[2:]) if fix else ():
        if bodies.shapes[0].phi(np.array([px]), np.array([py]))[0] >= 0:
            raise SceneError(f"{source}: key 'rigid.fix_x_points': ({px:g}, {py:g}) is not inside body 1")
    scene["rigid"]["fix_x_points"] = fix
    return scene, derived


def freefem_args(scene, mesh_file=""):
    """The script's flags: every key the schema declares, then the values derived here."""
    args = FreeFemFlags([f"-Ddegree={scene['method']['degree']}"])
    put_declared(args, scene, dict(scene=SCENE_HEADER, **SCHEMA))
    for i, (lam, mu) in enumerate(scene.lame, 1):
        args.put(f"lambda{i}", lam)
        args.put(f"mu{i}", mu)
    fix = scene["rigid"]["fix_x_points"]
    args.put("pins", int(bool(fix)))
    for key, value in zip(("fix_ax", "fix_ay", "fix_bx", "fix_by"), fix):
        args.put(key, value)
    return args


def prepare_mesh(scene, workdir, run_command):
    return ""      # the background mesh is a FreeFEM square
