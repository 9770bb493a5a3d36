"""The 3D shape "surface": a closed triangulated surface (STL or gmsh .msh) as a body.

The signed distance of the plugin (freefem/plugins/surface_distance.cpp) and of the
driver's checks (libigl) against closed forms (a notched cube, a prism with a sharp edge); the shipped scene
cases/torus_on_slab.toml balances on the volume its surface encloses; hostile files give
exit 2 and one line.
"""

import json
import math
import textwrap

import meshio
import numpy as np
import pytest

from driver.geometry import Box, Polygon, Surface
from driver.surface_input import enclosed_volume, surface_table
from lab.surfaces import TORUS, box, notched_cube, prism, torus, write_stl
from tests.conftest import REPO, run_cli, run_freefem

LO, SIDE = (-0.2, -0.2, -0.2), 0.4       # the notched cube: lab.surfaces.notched_cube(LO, SIDE, 2)
WEDGE, Z0, Z1 = [[-0.25, -0.05], [0.25, -0.05], [0.25, 0.05]], -0.1, 0.1   # an 11.3 degree edge at x = -0.25


def notched_cube_distance(points):
    """Closed form: outside, the distance to the union of the seven half-side cubes is the
    least of the distances to each (each box's exact signed distance); inside, the distance to
    the complement is the lesser of the distances to the whole cube's outside and to the
    notch, the missing eighth."""
    half, lo = SIDE / 2, np.array(LO)
    cubes = {c: Box(3, None, None, list(lo + half * np.array(c)), list(lo + half * (np.array(c) + 1)), 0.0)
             for c in np.ndindex(2, 2, 2)}
    to_filled = np.min([b.phi_local(*points.T) for c, b in cubes.items() if c != (1, 1, 1)], axis=0)
    whole = Box(3, None, None, list(lo), list(lo + SIDE), 0.0).phi_local(*points.T)
    to_outside = np.minimum(-whole, cubes[(1, 1, 1)].phi_local(*points.T))
    return np.where(to_filled > 0, to_filled, -to_outside)


def prism_distance(points):
    """Closed form of an extrusion: from the triangle's exact signed distance in (x, y) and the
    distance beyond the ends in z."""
    across = Polygon(2, None, None, [[tuple(c) for c in WEDGE]]).phi_local(points[:, 0], points[:, 1])
    along = np.abs(points[:, 2] - (Z0 + Z1) / 2) - (Z1 - Z0) / 2
    return np.minimum(np.maximum(across, along), 0.0) + np.hypot(np.maximum(across, 0.0), np.maximum(along, 0.0))


SHAPES = {"notched cube": (lambda: notched_cube(LO, SIDE, 2), notched_cube_distance),
          "sharp prism": (lambda: prism(WEDGE, Z0, Z1), prism_distance)}


def points_near(points, triangles, seed=1):
    """Points all over and around a surface and within 1e-3 and 1e-6 of each vertex of its
    triangulation and of each edge's midpoint, in random directions (inside and outside)."""
    rng = np.random.default_rng(seed)
    edges = np.unique(np.sort(np.vstack([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1),
                      axis=0)
    anchors = np.vstack([points, points[edges].mean(axis=1)])
    near = [np.repeat(anchors, 40, axis=0) + scale * rng.normal(size=(40 * len(anchors), 3)) for scale in (1e-3, 1e-6)]
    return np.vstack([rng.uniform(-0.5, 0.5, (1500, 3)), *near])


SCRIPT = """\
include "freefem/lib/fd3d/surface.idp"
int surface = surfaceFromTable("{table}");
ifstream in(sceneFolder() + "points.txt");
int n;
in >> n;
real[int] d(n);
for (int i = 0; i < n; i++) {{
    real x, y, z;
    in >> x >> y >> z;
    d[i] = surfaceDistance(surface, x, y, z);
}}
ofstream out(sceneFolder() + "distances.txt");
out.precision(17);
for (int i = 0; i < n; i++) out << d[i] << endl;
"""


def plugin_distances(folder, table, points):
    """surfaceDistance at the points, from a script beside the table (as a run's module)."""
    (folder / "table.txt").write_text(table)
    np.savetxt(folder / "points.txt", points, header=str(len(points)), comments="", fmt="%.17g")
    (folder / "distances.edp").write_text(SCRIPT.format(table="table.txt"))
    proc = run_freefem(folder / "distances.edp")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return np.loadtxt(folder / "distances.txt")


@pytest.mark.freefem
@pytest.mark.parametrize("name", sorted(SHAPES))
def test_plugin_distance_matches_a_closed_form(tmp_path, name):
    """The cube [-0.2, 0.2]^3 without its upper octant (192 triangles: convex, concave and
    saddle corners) and a prism on a triangle with an 11.3 degree corner (8 triangles): at
    points within 1e-3 or 1e-6 of every vertex and edge midpoint (30,880 and 1,440) and 1,500
    all over, the plugin's signed distance equals the closed form to 1.1e-16 (measured; 1e-24
    on the cube), every sign right: near the prism's sharp edge the sign of the nearest
    triangle's own normal is wrong at 169 of the points, the pseudo-normals' right."""
    make, closed_form = SHAPES[name]
    surface = make()
    points = points_near(*surface)
    exact = closed_form(points)
    d = plugin_distances(tmp_path, surface_table(*surface), points)
    assert np.abs(d - exact).max() < 1e-15
    assert np.array_equal(d < 0, exact < 0)


@pytest.mark.freefem
def test_plugin_distance_equals_the_drivers_on_the_torus(tmp_path):
    """On the shipped torus (1,536 triangles; 1,500 points all over, 800 within 1e-3 of its
    vertices) the plugin's signed distance equals libigl's (the driver's checks) to the bit."""
    surface = Surface(3, None, None, *torus(**TORUS))
    rng = np.random.default_rng(2)
    near = surface.points[rng.integers(0, len(surface.points), 800)] + 1e-3 * rng.normal(size=(800, 3))
    points = np.vstack([rng.uniform(-0.5, 0.5, (1500, 3)), near])
    d = plugin_distances(tmp_path, surface.table, points)
    assert np.abs(d - surface.phi_local(*points.T)).max() < 1e-15


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_driver_distance_matches_a_closed_form(name):
    """The driver's side (libigl, pseudo-normal sign) at the same points: within 1.1e-16 (measured)."""
    make, closed_form = SHAPES[name]
    surface = make()
    points = points_near(*surface)
    exact = closed_form(points)
    d = Surface(3, None, None, *surface).phi_local(*points.T)
    assert np.abs(d - exact).max() < 1e-15
    assert np.array_equal(d < 0, exact < 0)


@pytest.mark.freefem
def test_a_malformed_table_stops_a_direct_run_as_bad_input(tmp_path):
    table = surface_table(*notched_cube(LO, SIDE, 1)).replace("0.2", "nan", 1)
    (tmp_path / "table.txt").write_text(table)
    (tmp_path / "points.txt").write_text("1\n0 0 0\n")
    (tmp_path / "distances.edp").write_text(SCRIPT.format(table="table.txt"))
    proc = run_freefem(tmp_path / "distances.edp")
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "INPUT ERROR: the surface table table.txt" in proc.stdout + proc.stderr
    assert not (tmp_path / "distances.txt").exists()


@pytest.mark.freefem
def test_torus_scene_balances_on_the_volume_its_surface_encloses(run_scene):
    """cases/torus_on_slab.toml as shipped (nx = 13, P1, the curved cut geometry; about 13 s):
    results.json's exact volume is the one the triangles enclose (2.8 % below the smooth
    torus's 2 pi^2 R r^2); the cut cells integrate it within 1e-6 (measured 3.9e-7; at nx = 9
    3.7e-5: the signed distance bends on the surface's edges, which a cell's rule follows only
    by refining; the P1 geometry is 11 % low at nx = 13), the contact carries the weight."""
    run = run_scene("cases/torus_on_slab.toml", "output.vtu=false", "output.estimators=false", "output.csv=false")
    r = run.results
    points, triangles = torus(**TORUS)
    enclosed = enclosed_volume(points, triangles)
    assert enclosed == pytest.approx(2 * math.pi ** 2 * 0.25 * 0.1 ** 2 * (1 - 0.0283), rel=1e-3)
    assert r["measures"]["body1_exact"] == pytest.approx(enclosed, rel=1e-12)
    assert r["measures"]["body1"] == pytest.approx(enclosed, rel=1e-6)
    assert r["balance"]["balance_error"] < 1e-6 and not r["balance"]["unbalanced"]
    assert r["contact"]["force_on_body1"][2] == pytest.approx(0.1 * r["measures"]["body1"], rel=1e-6)
    assert len(list(run.folder.glob("surface-*.txt"))) == 1     # the table, beside scene.idp


@pytest.mark.freefem
def test_a_surface_slab_as_body_2_gives_the_half_space_slabs_run(tmp_path, run_scene):
    """cases/ball_on_slab.toml (nx = 8) with its slab {z < -0.25} given as the STL of the box
    [-0.6, 0.6]^2 x [-0.6, -0.25] (108 triangles, held on the box face zmin): the same zero level
    set near the contact, so the same run: the probe's displacement within 3.8e-12, the contact
    force within 1.7e-14 (measured), the same active area; the box clips the surface, so no exact
    volume."""
    write_stl(tmp_path / "slab.stl", *box((-0.6, -0.6, -0.6), (0.6, 0.6, -0.25), 3))
    text = (REPO / "cases" / "ball_on_slab.toml").read_text()
    text = text.replace('shape = "slab"', 'shape = { type = "surface", file = "slab.stl" }\nhold = [{ face = "zmin" }]')
    (tmp_path / "scene.toml").write_text(text.replace("top = -0.25", ""))
    small = ("mesh.nx=8", "output.vtu=false", "output.estimators=false", "output.csv=false")
    surface = run_scene(str(tmp_path / "scene.toml"), *small).results
    slab = run_scene("cases/ball_on_slab.toml", *small).results
    assert surface["probes"]["centre"][2] == pytest.approx(slab["probes"]["centre"][2], rel=4e-11)
    assert surface["contact"]["force_on_body1"][2] == pytest.approx(slab["contact"]["force_on_body1"][2], rel=1e-12)
    assert surface["contact"]["active_measure"] == pytest.approx(slab["contact"]["active_measure"], rel=1e-12)
    assert surface["measures"]["body2_exact"] is None and slab["measures"]["body2_exact"] == 0.25


@pytest.mark.freefem
def test_a_failed_run_keeps_the_surface_table_with_its_inputs(tmp_path):
    """A run stopped by its Newton limit (exit 3) leaves RUN.failed with scene.idp and the table
    it reads (so it can be rerun), and no results.json."""
    proc = run_cli("run", "cases/torus_on_slab.toml", "--set", "mesh.nx=9", "--set", "solver.newton_max=1",
                   "--set", "output.vtu=false", "--out", str(tmp_path / "run"))
    assert proc.returncode == 3, proc.stderr[-2000:]
    failed = tmp_path / "run.failed"
    assert (failed / "scene.idp").is_file() and not (failed / "results.json").exists()
    tables = list(failed.glob("surface-*.txt"))
    assert len(tables) == 1 and tables[0].name in (failed / "scene.idp").read_text()


# ---- hostile files -------------------------------------------------------------------------------

SCENE = (REPO / "cases" / "torus_on_slab.toml").read_text().replace('"geo/torus.stl"', '"{file}"')


def scene_with(folder, file):
    path = folder / "scene.toml"
    path.write_text(SCENE.replace("{file}", file))
    return path


def one_error(proc, *words):
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    for word in words:
        assert word in lines[0], lines[0]


def torus_stl(folder, name="part.stl", edit=None):
    points, triangles = torus(**TORUS)
    if edit:
        points, triangles = edit(points.copy(), triangles.copy())
    write_stl(folder / name, points, triangles)
    return name


def test_a_clean_surface_is_accepted_as_stl_binary_stl_and_msh(tmp_path):
    """The shipped torus as ascii STL, binary STL and gmsh .msh: the module reads its table and
    states the volume the surface encloses (the binary STL's float32 coordinates: within 1e-7)."""
    points, triangles = torus(**TORUS)
    mesh = meshio.Mesh(points, [("triangle", triangles)])
    meshio.stl.write(str(tmp_path / "binary.stl"), mesh, binary=True)
    meshio.gmsh.write(str(tmp_path / "part.msh"), mesh, fmt_version="2.2", binary=False)
    modules = []
    for name in (torus_stl(tmp_path), "binary.stl", "part.msh"):
        proc = run_cli("scene-module", str(scene_with(tmp_path, name)), cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert "surfaceDistance(surfaceTable" in proc.stdout
        modules.append(float(proc.stdout.split("real exactMeasure1 = ")[1].split(";")[0]))
    enclosed = enclosed_volume(points, triangles)
    assert modules == pytest.approx([enclosed, enclosed, enclosed], rel=1e-7)
    assert modules[0] == pytest.approx(enclosed, rel=1e-14) and modules[2] == pytest.approx(enclosed, rel=1e-14)


def test_scale_reads_a_surface_in_other_units(tmp_path):
    """The torus written in millimetres and read with scale = 0.001 gives the module of the
    torus in metres: the same exact volume (to 1e-12) and a table of the scaled coordinates."""
    torus_stl(tmp_path, "metres.stl")
    torus_stl(tmp_path, "mm.stl", edit=lambda p, t: (1000 * p, t))
    metres = run_cli("scene-module", str(scene_with(tmp_path, "metres.stl")), cwd=tmp_path)
    path = tmp_path / "scene.toml"
    path.write_text(SCENE.replace('"{file}"', '"mm.stl", scale = 0.001'))
    mm = run_cli("scene-module", str(path), cwd=tmp_path)
    assert metres.returncode == 0 and mm.returncode == 0, metres.stderr + mm.stderr

    def volume(module):
        return float(module.split("real exactMeasure1 = ")[1].split(";")[0])
    assert volume(mm.stdout) == pytest.approx(volume(metres.stdout), rel=1e-12)
    path.write_text(SCENE.replace('"{file}"', '"mm.stl", scale = -1.0'))
    one_error(run_cli("scene-module", str(path), cwd=tmp_path), "body1.shape.scale: must be a number > 0")


def flip_one(points, triangles):
    triangles[7] = triangles[7][::-1]
    return points, triangles


def garbage(folder):
    (folder / "part.stl").write_bytes(np.random.default_rng(3).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    return "part.stl"


def linked_outside(folder):
    (folder / "link.stl").symlink_to(folder.parent / "torus.stl")
    return "link.stl"


def too_many(folder):
    points, triangles = torus(0.25, 0.1, 160, 160, (0.0, 0.0, -0.15))
    meshio.stl.write(str(folder / "part.stl"), meshio.Mesh(points, [("triangle", triangles)]), binary=True)
    return "part.stl"


def tetrahedra(folder):
    points = np.array([[0, 0, -0.2], [0.1, 0, -0.2], [0, 0.1, -0.2], [0, 0, -0.1]], float)
    meshio.gmsh.write(str(folder / "part.msh"), meshio.Mesh(points, [("tetra", np.array([[0, 1, 2, 3]]))]),
                      fmt_version="2.2", binary=False)
    return "part.msh"


HOSTILE = {
    "open": (lambda f: torus_stl(f, edit=lambda p, t: (p, t[1:])), "not closed: 3 edges belong to one triangle"),
    "inward": (lambda f: torus_stl(f, edit=lambda p, t: (p, t[:, ::-1])), "oriented inward"),
    "one flipped": (lambda f: torus_stl(f, edit=flip_one), "not consistently oriented: 3 edges"),
    "garbage": (garbage, "not a readable STL file"),
    "empty": (lambda f: (f / "part.stl").write_text("") or "part.stl", "'part.stl' is empty"),
    "nan": (lambda f: torus_stl(f, edit=lambda p, t: (np.where(np.arange(len(p))[:, None] == 5, np.nan, p), t)),
            "coordinates that are not finite"),
    "absolute": (lambda f: str(REPO / "cases" / "geo" / "torus.stl"), "is an absolute path"),
    "parent": (lambda f: "../torus.stl", "lies outside the scene's folder"),
    "symlink": (linked_outside, "lies outside the scene's folder"),
    "too many": (too_many, "51200 triangles; at most 50000"),
    "tetrahedra": (tetrahedra, "holds tetra elements"),
    "wrong suffix": (lambda f: torus_stl(f, "part.obj"), "is not a .stl or .msh file"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_a_hostile_surface_file_gives_exit_2_and_one_line(tmp_path, case):
    make, cause = HOSTILE[case]
    folder = tmp_path / "scenes"
    folder.mkdir()
    (tmp_path / "torus.stl").write_text((REPO / "cases" / "geo" / "torus.stl").read_text())
    name = make(folder)
    proc = run_cli("run", str(scene_with(folder, name)), "--out", str(tmp_path / "run"), cwd=tmp_path)
    one_error(proc, "body1.shape.file", cause)
    assert not (tmp_path / "run").exists()
