"""Scenes for freefem/contact_foundation_2d.edp: one body, rigid foundation, fitted mesh.

The body is the box (geometry.kind = box, sides labelled bottom, right, top,
left) or a gmsh mesh of a .geo file (sides labelled by physical id); each side
named in a [[boundary]] table gets a displacement, a traction or contact with the
rigid foundation {(x - foundation_point).foundation_normal <= 0}; the others are
free. Rules across keys (check below): the material gives E and nu or lambda and
mu (not both); the box is not empty; kind = gmsh needs an existing geo file;
reference.folder holds a saved solution (mesh.msh, u.txt); foundation_normal is
not zero; boundary labels exist on the mesh.
"""

import copy
from pathlib import Path

from . import gmsh_input
from .errors import SceneError
from .materials import young_from_lame
from .header import SCENE_HEADER
from .schema import (ADAPT_SCHEMA, Field, FreeFemFlags, TableList, at_least, open_interval,
                           positive, put_declared)

BOX_LABELS = {"bottom": 1, "right": 2, "top": 3, "left": 4}
COMPONENT_BITS = {"x": 1, "y": 2, "xy": 3}

SCHEMA = {
    "geometry": {
        "kind": Field("str", derived="meshfile", default="box", choices=("box", "gmsh"),
                      doc="box: FreeFEM square mesh of the box; gmsh: mesh of geometry.geo"),
        "xmin": Field("float", flag="xmin", default=0.0, unit="length", doc="box, left side (kind = box)"),
        "xmax": Field("float", flag="xmax", default=1.0, unit="length", doc="box, right side (> xmin)"),
        "ymin": Field("float", flag="ymin", default=0.0, unit="length", doc="box, bottom"),
        "ymax": Field("float", flag="ymax", default=1.0, unit="length", doc="box, top (> ymin)"),
        "geo": Field("str", derived="meshfile", default="",
                     doc="gmsh .geo file (kind = gmsh), relative to the scene"),
    },
    "mesh": {
        "nx": Field("int", flag="nx", default=32, check=positive,
                    doc="elements across the box's width, as in the two-body scripts (h = width/nx; a gmsh "
                        "geometry is meshed at its width/nx)"),
    },
    "material": {
        "E": Field("float", derived="E nu", default=None, check=positive, unit="stress",
                   doc="Young's modulus (give E and nu, or lambda and mu)"),
        "nu": Field("float", derived="E nu", default=None, check=open_interval(-1.0, 0.5), unit="1",
                    doc="Poisson's ratio (with E)"),
        "lambda": Field("float", derived="E nu", default=None, unit="stress",
                        doc="first Lame coefficient (with mu; the implied nu must lie in (-1, 0.5))"),
        "mu": Field("float", derived="E nu", default=None, check=positive, unit="stress",
                    doc="shear modulus (with lambda)"),
        "plane": Field("str", derived="planestress", default="strain", choices=("strain", "stress"),
                       doc="plane strain or plane stress"),
    },
    "loads": {
        "body_force": Field("vector", flag=("fx", "fy"), default=[0.0, 0.0], length=2, unit="force/volume",
                            doc="volume force"),
    },
    "boundary": TableList({
        "label": Field("str", derived="dirichlet{i}_label traction{i}_label contact{i}_label",
                       doc="bottom/right/top/left for boxes, a physical id for gmsh"),
        "type": Field("str", derived="ndirichlet ntraction ncontact",
                      choices=("dirichlet", "traction", "contact", "free"),
                      doc="condition on that boundary: displacement, traction, contact with the foundation, none"),
        "value": Field("vector", derived="dirichlet{i}_ux dirichlet{i}_uy traction{i}_tx traction{i}_ty",
                       default=[0.0, 0.0], length=2, unit="length or force/area",
                       doc="imposed displacement (dirichlet) or traction (traction)"),
        "components": Field("str", derived="dirichlet{i}_fix", default="xy", choices=tuple(COMPONENT_BITS),
                            doc="displacement components a dirichlet condition fixes"),
    }),
    "point_constraint": TableList({
        "point": Field("vector", derived="npoint point{i}_x point{i}_y", length=2, unit="length",
                       doc="u = 0 at the node lying at this point (to 1e-9)"),
        "components": Field("str", derived="point{i}_fix", default="x", choices=tuple(COMPONENT_BITS),
                            doc="components fixed there"),
    }),
    "contact": {
        "foundation_point": Field("vector", flag=("foundation_px", "foundation_py"), default=[0.0, 0.0], length=2,
                                  unit="length",
                                  doc="a point of the rigid foundation's boundary line"),
        "foundation_normal": Field("vector", flag=("foundation_nx", "foundation_ny"),
                                   default=[0.0, 1.0], length=2, unit="1",
                                   doc="normal of that line pointing out of the foundation (non-zero; gap = "
                                       "(x - point).normal)"),
    },
    "method": {
        "degree": Field("int", derived="Ddegree", default=2, choices=(1, 2),
                        doc="finite element degree (P1 or P2)"),
        "theta": Field("float", flag="theta", default=-1.0, unit="1",
                       doc="Nitsche variant: 1 symmetric, 0 non-symmetric, -1 skew-symmetric (any real)"),
        "gamma0": Field("float", flag="gamma0", default=1.0, check=positive, unit="1",
                        doc="gamma = gamma0 h_K / E (gamma_scaling young)"),
        "gamma_scaling": Field("str", flag="gamma_scaling", default="young", choices=("young", "none"),
                               doc="young: gamma = gamma0 h_K / E (gamma0 dimensionless); "
                                   "none: gamma = gamma0 h_K (gamma0 in 1/stress)"),
    },
    "solver": {
        "newton_tol": Field("float", flag="newton_tol", default=1e-9, check=positive, unit="1",
                            doc="Newton stops when the relative residual is below this and the active set is stable"),
        "newton_max": Field("int", flag="newton_max", default=30, check=at_least(1),
                            doc="Newton iteration limit (then exit 3)"),
    },
    "adapt": ADAPT_SCHEMA,
    "reference": {
        "folder": Field("str", derived="reference", default="",
                        doc="a run saved with output.save_solution (P2): errors against it"),
    },
    "output": {
        "vtu": Field("bool", flag="vtu", default=True, doc="write fields.vtu"),
        "pressure_csv": Field("bool", flag="csv", default=True,
                              doc="write contact_pressure.csv (when a boundary has contact)"),
        "save_solution": Field("bool", flag="save", default=False, doc="write mesh.msh and u.txt (a reference)"),
    },
}


def check(tables, source, base_dir):
    """Cross-field rules the schema cannot express: (the tables, a copy with the reference
    folder made absolute; the derived values young_nu, geo_path, label_ids). `tables` is left
    as it was; files it names are read from base_dir."""
    scene = copy.deepcopy(tables)
    mat = scene["material"]
    if mat["E"] is not None and mat["nu"] is not None:
        if mat["lambda"] is not None or mat["mu"] is not None:
            raise SceneError(f"{source}: key 'material': give either E and nu or lambda and mu, not both")
        young_nu = (mat["E"], mat["nu"])
    elif mat["lambda"] is not None and mat["mu"] is not None:
        young_nu = young_from_lame(mat["lambda"], mat["mu"])
        if not -1.0 < young_nu[1] < 0.5:
            raise SceneError(f"{source}: key 'material.lambda': gives a Poisson ratio {young_nu[1]:.4g} "
                             f"outside (-1, 0.5)")
    else:
        raise SceneError(f"{source}: key 'material': needs E and nu (or lambda and mu)")
    geo, geo_path = scene["geometry"], None
    if geo["kind"] == "box":
        if not (geo["xmax"] > geo["xmin"] and geo["ymax"] > geo["ymin"]):
            raise SceneError(f"{source}: key 'geometry': the box is empty (need xmax > xmin, ymax > ymin)")
    elif not geo["geo"]:
        raise SceneError(f"{source}: key 'geometry.geo': required when geometry.kind = 'gmsh'")
    else:
        where = f"{source}: key 'geometry.geo'"
        geo_path = gmsh_input.file_inside(base_dir, geo["geo"], where, (".geo",))
        gmsh_input.check_mesh_sizes(gmsh_input.read_geo(geo_path, where), where)
    folder = scene["reference"]["folder"]
    if folder:
        path = Path(folder)
        if not path.is_absolute():
            path = (Path.cwd() / path)
        if not (path / "u.txt").is_file() or not (path / "mesh.msh").is_file():
            raise SceneError(f"{source}: key 'reference.folder': no saved solution (mesh.msh, u.txt) in {path}")
        scene["reference"]["folder"] = str(path.resolve())
    normal = scene["contact"]["foundation_normal"]
    if normal[0] ** 2 + normal[1] ** 2 == 0:
        raise SceneError(f"{source}: key 'contact.foundation_normal': must be non-zero")
    label_ids = tuple(label_id(bc["label"], geo["kind"], f"{source}: key 'boundary.{n}.label'")
                      for n, bc in enumerate(scene["boundary"]))
    return scene, {"young_nu": young_nu, "geo_path": geo_path, "label_ids": label_ids}


def label_id(label, kind, where):
    if kind == "box":
        if label not in BOX_LABELS:
            raise SceneError(f"{where}: a box has the sides {', '.join(BOX_LABELS)}, got {label!r}")
        return BOX_LABELS[label]
    if not label.isdigit():
        raise SceneError(f"{where}: a gmsh mesh labels boundaries by physical id (an integer), got {label!r}")
    return int(label)


def freefem_args(scene, mesh_file=""):
    """The script's flags: every key the schema declares, then the values derived here."""
    mat = scene["material"]
    args = FreeFemFlags([f"-Ddegree={scene['method']['degree']}"])
    put = args.put
    put_declared(args, scene, dict(scene=SCENE_HEADER, **SCHEMA))
    put("meshfile", mesh_file)
    put("E", scene.young_nu[0])
    put("nu", scene.young_nu[1])
    put("planestress", int(mat["plane"] == "stress"))
    by_type = {t: [(bc, label) for bc, label in zip(scene["boundary"], scene.label_ids) if bc["type"] == t]
               for t in ("dirichlet", "traction", "contact")}
    put("ndirichlet", len(by_type["dirichlet"]))
    for i, (bc, label) in enumerate(by_type["dirichlet"]):
        put(f"dirichlet{i}_label", label)
        put(f"dirichlet{i}_fix", COMPONENT_BITS[bc["components"]])
        put(f"dirichlet{i}_ux", bc["value"][0])
        put(f"dirichlet{i}_uy", bc["value"][1])
    put("ntraction", len(by_type["traction"]))
    for i, (bc, label) in enumerate(by_type["traction"]):
        put(f"traction{i}_label", label)
        put(f"traction{i}_tx", bc["value"][0])
        put(f"traction{i}_ty", bc["value"][1])
    put("ncontact", len(by_type["contact"]))
    for i, (bc, label) in enumerate(by_type["contact"]):
        put(f"contact{i}_label", label)
    put("npoint", len(scene["point_constraint"]))
    for i, pc in enumerate(scene["point_constraint"]):
        put(f"point{i}_x", pc["point"][0])
        put(f"point{i}_y", pc["point"][1])
        put(f"point{i}_fix", COMPONENT_BITS[pc["components"]])
    if scene["reference"]["folder"]:
        put("reference", scene["reference"]["folder"])
    return args


def prepare_mesh(scene, workdir, run_command):
    """Mesh files the script needs (gmsh scenes): returns the -meshfile value."""
    geo = scene["geometry"]
    if geo["kind"] != "gmsh":
        return ""
    where = f"{scene.source}: key 'geometry.geo'"
    records = gmsh_input.read_geo(scene.geo_path, where)
    width = gmsh_input.geo_extent(records, axis=0)
    msh = gmsh_input.mesh_geo(records, 2, width / scene["mesh"]["nx"], where, Path(workdir) / "mesh.msh",
                              scene["limits"]["gmsh_s"])
    return str(msh)


def summary_lines(results):
    contact = results.get("contact", {})
    box = contact.get("active_box", [])
    lines = []
    if box and box[0] <= box[2]:
        lines.append(
            f"contact zone: active length {contact['active_measure']:.4g}, "
            f"x in [{box[0]:.4g}, {box[2]:.4g}], y in [{box[1]:.4g}, {box[3]:.4g}]")
    else:
        lines.append("contact zone: empty (no active contact point)")
    est = results.get("estimator")
    if est:
        lines.append("estimator: eta {eta:.4g} (eta1 {eta1:.3g}, eta2 {eta2:.3g}, eta3 {eta3:.3g}, "
                     "eta4 {eta4:.3g}), zeta {zeta:.3g}".format(**est))
    steps = results.get("steps", {})
    if len(steps.get("dofs", [])) > 1:
        lines.append(f"adaptation: {len(steps['dofs'])} solves, DOFs {int(steps['dofs'][0])} -> "
                     f"{int(steps['dofs'][-1])}, eta {steps['eta'][0]:.4g} -> {steps['eta'][-1]:.4g}")
    if "reference" in results:
        ref = results["reference"]
        lines.append(f"error vs reference: L2 {steps['l2_error'][-1] / ref['l2_norm']:.3e}, "
                     f"H1 {steps['h1_error'][-1] / ref['h1_norm']:.3e} (relative)")
    force = contact.get("force_on_body", [0, 0])
    lines.append(f"contact force on body: ({force[0]:.6g}, {force[1]:.6g}), "
                 f"max pressure {contact.get('max_pressure', 0):.6g}, "
                 f"max penetration {contact.get('max_penetration', 0):.3g}")
    return lines
