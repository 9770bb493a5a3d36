"""Scenes for freefem/fd_contact_2d.edp: two bodies on one background mesh (fictitious domain).

Body 1 is a disk, body 2 a slab {y < top} of the box, held either strongly on the
box bottom or, with `bottom_line = [a, b]`, by Nitsche-Dirichlet on the line
y = a + b x that cuts the mesh.

Rules across keys (check below): the box is not empty; the disk lies inside the
box and not below the slab top; the slab top lies inside the box; a bottom_line
crosses the box between its bottom and the slab top, and then gamma_scaling is
shear or none; both fix_x_points lie inside the disk; each body gives lambda and
mu or E and nu (not both); adapt.steps > 0 needs output.estimators.
"""

from driver.errors import SceneError
from driver.materials import body_lame
from driver.schema import (ADAPT_SCHEMA, Field, FreeFemFlags, at_least, open_interval, positive, put_adapt,
                           two_body_solver_schema)

STABILIZATIONS = ("auto", "none", "neighbour", "ghost")
GAMMA_SCALINGS = ("shear", "none", "body1", "mean_compliance")


def body_schema(shape_fields, force):
    """A body's fields: its shape, Lame (or E, nu) and a volume force of len(force) components."""
    return dict(shape_fields, **{
        "lambda": Field("float", default=None, unit="stress",
                        doc="first Lame coefficient (give lambda and mu, or E and nu); lambda + mu > 0"),
        "mu": Field("float", default=None, check=positive, unit="stress", doc="shear modulus (with lambda)"),
        "E": Field("float", default=None, check=positive, unit="stress", doc="Young's modulus (with nu)"),
        "nu": Field("float", default=None, check=open_interval(-1.0, 0.5), unit="1",
                    doc="Poisson's ratio (with E; plane strain in 2D)"),
        "body_force": Field("vector", default=force, length=len(force), unit="force/volume",
                            doc="volume force on the body"),
    })


SCHEMA = {
    "geometry": {
        "xmin": Field("float", default=-0.5, unit="length", doc="background box, left side"),
        "xmax": Field("float", default=0.5, unit="length", doc="background box, right side (> xmin)"),
        "ymin": Field("float", default=-0.5, unit="length", doc="background box, bottom (the slab is clamped here)"),
        "ymax": Field("float", default=0.5, unit="length", doc="background box, top (> ymin)"),
    },
    "mesh": {
        "nx": Field("int", default=80, check=at_least(2), doc="elements per side of the box (h = width/nx)"),
    },
    "body1": body_schema({
        "shape": Field("str", default="disk", choices=("disk",), doc="body 1 is a disk, inside the box"),
        "centre": Field("vector", default=[0.0, 0.0], length=2, unit="length", doc="centre of the disk"),
        "radius": Field("float", default=0.25, check=positive, unit="length", doc="radius of the disk"),
    }, [0.0, -0.1]),
    "body2": body_schema({
        "shape": Field("str", default="slab", choices=("slab",), doc="body 2 is the part of the box below top"),
        "top": Field("float", default=-0.25, unit="length",
                     doc="height of the slab's top; not above the disk's lowest point"),
        "bottom_line": Field("vector", default=[], unit="length, 1",
                             doc="[a, b]: Nitsche-Dirichlet u = 0 on y = a + b x, crossing the box below top; "
                                 "[] clamps the box bottom strongly"),
    }, [0.0, 0.0]),
    "rigid": {
        "mass_eps": Field("float", default=1e-7, check=at_least(0.0), unit="1",
                          doc="mass term eps muStar int u1.v1 against the floating disk's rigid motions "
                              "(relative to the shear modulus muStar, see method.gamma_scaling)"),
        "fix_x_points": Field("vector", default=[0.0, 0.0, 0.0, 0.1], length=4, unit="length",
                              doc="u1_x = 0 at the nodes nearest to these two points (x1, y1, x2, y2), inside the disk"),
    },
    "method": {
        "degree": Field("int", default=2, choices=(1, 2), doc="finite element degree (P1 or P2)"),
        "theta": Field("float", default=-1.0, unit="1",
                       doc="Nitsche variant: 1 symmetric, 0 non-symmetric, -1 skew-symmetric (any real)"),
        "gamma0": Field("float", default=1.0 / 200.0, check=positive, unit="1",
                        doc="Nitsche parameter, gamma = gamma0 h_K / muStar (1/stress with gamma_scaling none)"),
        "stabilization": Field("str", default="auto", choices=STABILIZATIONS,
                               doc="auto: ghost for theta > 0 (coercivity on cut elements), none otherwise; "
                                   "neighbour: stress of the best-cut neighbour (R_rho); ghost: ghost penalty"),
        "rho": Field("float", default=0.25, check=open_interval(0.0, 1.0 + 1e-12, "(0, 1]"), unit="1",
                     doc="neighbour stabilization: cut ratio |K cap Omega_i|/|K| below which an element "
                         "borrows its neighbour's stress"),
        "ghost_gamma": Field("float", default=1e-2, check=positive, unit="1",
                             doc="ghost penalty weight, times lambda + 2 mu of each body"),
        "gamma_scaling": Field("str", default="shear", choices=GAMMA_SCALINGS,
                               doc="shear: gamma = gamma0 h_K / muStar, muStar = 2 mu1 mu2/(mu1 + mu2) (gamma0 "
                                   "dimensionless); none: gamma = gamma0 h_K (gamma0 in 1/stress); body1: "
                                   "gamma = gamma0 h_K / E1 (Young modulus of the disk, whose sigma_n enters the "
                                   "Nitsche terms); mean_compliance: gamma = gamma0 h_K (1/E1 + 1/E2)/2"),
    },
    "solver": dict(two_body_solver_schema("disk", Field(
        "int", default=3, choices=(1, 2, 3, 4), doc="Gauss points per cut segment")),
        time_final_solve=Field("bool", default=False,
                               doc="benchmarks: time one extra factorization and solve of the final system")),
    "adapt": dict(ADAPT_SCHEMA, warm_start=Field(
        "int", default=1, choices=(0, 1, 2),
        doc="Newton start after adaptation: 0 default, 1 previous active measure, 2 previous solution")),
    "output": {
        "vtu": Field("bool", default=True, doc="write fields.vtu"),
        "pressure_csv": Field("bool", default=True, doc="write contact_pressure.csv"),
        "estimators": Field("bool", default=True,
                            doc="residual estimators eta_1..eta_5 (needed by adapt.steps > 0)"),
        "save_solution": Field("bool", default=False,
                               doc="write meshes and DOF arrays (a reference; every step when adapting)"),
        "export_matrix": Field("bool", default=False,
                               doc="write the last Newton matrix on the free DOFs (newton_matrix.mtx, MatrixMarket)"),
    },
}


def check(scene, source):
    geo = scene["geometry"]
    if not (geo["xmax"] > geo["xmin"] and geo["ymax"] > geo["ymin"]):
        raise SceneError(f"{source}: key 'geometry': the box is empty (need xmax > xmin, ymax > ymin)")
    for key in ("body1", "body2"):
        scene[key]["lame"] = body_lame(scene[key], source, key)
    disk = scene["body1"]
    (cx, cy), r = disk["centre"], disk["radius"]
    if cx - r <= geo["xmin"] or cx + r >= geo["xmax"] or cy - r <= geo["ymin"] or cy + r >= geo["ymax"]:
        raise SceneError(f"{source}: key 'body1': the disk (centre {disk['centre']}, radius {r}) "
                         f"is not inside the box")
    slab = scene["body2"]
    if not geo["ymin"] < slab["top"] < geo["ymax"]:
        raise SceneError(f"{source}: key 'body2.top': the slab top {slab['top']} misses the box "
                         f"({geo['ymin']}, {geo['ymax']})")
    if cy - r < slab["top"] - 1e-12:
        raise SceneError(f"{source}: key 'body1': the disk overlaps the slab initially "
                         f"(lowest point {cy - r:g} < slab top {slab['top']:g})")
    line = slab["bottom_line"]
    if line:
        if len(line) != 2:
            raise SceneError(f"{source}: key 'body2.bottom_line': expected [a, b] (y = a + b x), got {line}")
        a, b = line
        ends = (a + b * geo["xmin"], a + b * geo["xmax"])
        if not all(geo["ymin"] <= y < slab["top"] for y in ends):
            raise SceneError(f"{source}: key 'body2.bottom_line': the line y = {a:g} + {b:g} x must cross "
                             f"the box between its bottom and the slab top")
    if scene["adapt"]["steps"] > 0 and not scene["output"]["estimators"]:
        raise SceneError(f"{source}: key 'output.estimators': adaptation (adapt.steps > 0) needs the estimators")
    if line and scene["method"]["gamma_scaling"] not in ("none", "shear"):
        raise SceneError(f"{source}: key 'method.gamma_scaling': {scene['method']['gamma_scaling']!r} scales "
                         f"the contact gamma by the moduli; with body2.bottom_line use 'shear' or 'none'")
    fix = scene["rigid"]["fix_x_points"]
    for px, py in (fix[:2], fix[2:]):
        if (px - cx) ** 2 + (py - cy) ** 2 >= r ** 2:
            raise SceneError(f"{source}: key 'rigid.fix_x_points': ({px:g}, {py:g}) is not inside the disk")


def freefem_args(scene, mesh_file=""):
    geo, meth, solver = scene["geometry"], scene["method"], scene["solver"]
    disk, slab = scene["body1"], scene["body2"]
    args = FreeFemFlags([f"-Ddegree={meth['degree']}"])
    put = args.put

    put("name", scene["scene"]["name"])
    for key in ("xmin", "xmax", "ymin", "ymax"):
        put(key, geo[key])
    put("nx", scene["mesh"]["nx"])
    put("disk_cx", disk["centre"][0])
    put("disk_cy", disk["centre"][1])
    put("disk_r", disk["radius"])
    put("slab_top", slab["top"])
    if slab["bottom_line"]:
        put("slab_bottom_a", slab["bottom_line"][0])
        put("slab_bottom_b", slab["bottom_line"][1])
    for i, body in ((1, disk), (2, slab)):
        put(f"lambda{i}", body["lame"][0])
        put(f"mu{i}", body["lame"][1])
        put(f"f{i}x", body["body_force"][0])
        put(f"f{i}y", body["body_force"][1])
    put("mass_eps", scene["rigid"]["mass_eps"])
    fix = scene["rigid"]["fix_x_points"]
    for key, value in zip(("fix_ax", "fix_ay", "fix_bx", "fix_by"), fix):
        put(key, value)
    put("theta", meth["theta"])
    put("gamma0", meth["gamma0"])
    put("stabilization", meth["stabilization"])
    put("rho", meth["rho"])
    put("ghost_gamma", meth["ghost_gamma"])
    put("gamma_scaling", meth["gamma_scaling"])
    put("newton_tol", solver["newton_tol"])
    put("newton_max", solver["newton_max"])
    put("contact_qp", solver["contact_points"])
    put("active0", solver["active0"])
    put("predictor_steps", solver["predictor_steps"])
    put("refactor_points", solver["refactor_points"])
    put("time_final_solve", int(solver["time_final_solve"]))
    put("allow_unbalanced", int(solver["allow_unbalanced"]))
    put_adapt(args, scene["adapt"])
    put("adapt_warm_start", scene["adapt"]["warm_start"])
    put("vtu", int(scene["output"]["vtu"]))
    put("csv", int(scene["output"]["pressure_csv"]))
    put("save", int(scene["output"]["save_solution"]))
    put("estimators", int(scene["output"]["estimators"]))
    put("export_matrix", int(scene["output"]["export_matrix"]))
    return args


def prepare_mesh(scene, workdir, run_command):
    return ""      # the background mesh is a FreeFEM square


def summary_lines(results):
    contact, cut = results["contact"], results["cut"]
    centre = results["disk"]["centre_displacement"]
    lines = []
    est = results.get("estimator")
    if est:
        lines.append("estimator: eta {eta:.4g} (eta1 {eta1:.3g}, eta2 {eta2:.3g}, eta3 {eta3:.3g}, eta4 {eta4:.3g}, "
                     "eta5 {eta5:.3g}), zeta {zeta:.3g}".format(**est))
    steps = results.get("steps", {})
    if len(steps.get("dofs", [])) > 1:
        lines.append(f"adaptation: {len(steps['dofs'])} solves, DOFs {int(steps['dofs'][0])} -> "
                     f"{int(steps['dofs'][-1])}, eta {steps['eta'][0]:.4g} -> {steps['eta'][-1]:.4g}, "
                     f"disk area {steps['area_body1'][0]:.6f} -> {steps['area_body1'][-1]:.6f}")
    balance = results.get("balance")
    if balance and balance.get("unbalanced"):
        lines.append(f"UNBALANCED (kept by solver.allow_unbalanced): {balance['message']}")
    return lines + [
        f"bodies: {results['dofs_body1']} + {results['dofs_body2']} DOFs on the cut spaces, "
        f"areas {results['areas']['body1']:.6g} and {results['areas']['body2']:.6g}",
        f"disk centre displacement: ({centre[0]:.6g}, {centre[1]:.6g})",
        f"contact: active length {contact['active_length']:.4g} of {contact['boundary_length']:.4g}, "
        f"force on disk ({contact['force_on_body1'][0]:.4g}, {contact['force_on_body1'][1]:.6g}), "
        f"balance error {contact['force_balance_error']:.1e}, max pressure {contact['max_pressure']:.4g}",
        f"cut elements: min ratio {cut['min_ratio_body1']:.2e} (disk), {cut['min_ratio_body2']:.2e} (slab); "
        f"stabilization {cut['stabilization']}: cases a/b/c = {cut['case_a']}/{cut['case_b']}/{cut['case_c']}, "
        f"sliver elements dropped {cut.get('dropped_body1', 0)} + {cut.get('dropped_body2', 0)}",
    ]
