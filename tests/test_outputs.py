"""The outputs a user reads: the per-body VTU files (2D and 3D, same names, P2 nodal values
kept, nothing away from a body) and the recovered contact pressure (on closed-form
pressures, and in a run's CSV and results.json)."""

import json

import meshio
import numpy as np
import pandas as pd
import pytest

from conftest import REPO, run_freefem

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)

BODY_FIELDS = {"displacement", "von_mises", "phi"}
BODY1_CELL_FIELDS = {"contact_pressure", "contact_pressure_recovered", "cut_ratio"}


@pytest.fixture(scope="module")
def run_p2(tmp_path_factory):
    """Disk on slab, P2, NX = 10, with its saved solution (the P2 field itself)."""
    from conftest import run_cli

    out = tmp_path_factory.mktemp("outputs") / "run"
    proc = run_cli("run", str(REPO / "cases/disk_on_slab.toml"), "--out", str(out), "--set", "mesh.nx=10",
                   "--set", "output.save_solution=true", "--set", "output.estimators=false")
    assert proc.returncode == 0, proc.stderr
    return out


def read_body(folder, body):
    return meshio.read(folder / f"body{body}.vtu")


def test_body_files_2d_fields_and_p2_nodes(run_p2):
    results = json.loads((run_p2 / "results.json").read_text())
    assert results["degree"] == 2
    assert results["outputs"]["vtu_body1"] == "body1.vtu" and results["outputs"]["vtu_body2"] == "body2.vtu"
    for body in (1, 2):
        mesh = read_body(run_p2, body)
        assert BODY_FIELDS <= set(mesh.point_data), (body, list(mesh.point_data))
        # every P2 node of the body's space is a point of the file: ndof / 2 components
        assert len(mesh.points) == results[f"dofs_body{body}"] // 2, body
        cells = set(mesh.cell_data)
        if body == 1:
            assert BODY1_CELL_FIELDS <= cells, cells
        # nothing away from the body: every point is within one element of it
        assert mesh.point_data["phi"].max() <= 1.5 * results["h"], body
        assert (mesh.point_data["phi"] < 0).any(), body
    pressure = read_body(run_p2, 1).cell_data
    assert max(np.max(block) for block in pressure["contact_pressure"]) > 0
    assert min(np.min(block) for block in pressure["contact_pressure_recovered"]) >= 0


def test_body_file_values_are_the_p2_field_at_its_nodes(run_p2, tmp_path):
    """The displacement written at the split mesh's vertices equals the P2 field (the saved
    solution, evaluated by FreeFEM) at those points, up to the float32 coordinates of the
    file; and the midpoints carry P2 detail (they differ from their edge's mean)."""
    mesh = read_body(run_p2, 1)
    points = np.asarray(mesh.points[:, :2], dtype=float)
    values = np.asarray(mesh.point_data["displacement"], dtype=float)[:, :2]
    listing = tmp_path / "points.txt"
    listing.write_text(f"{len(points)}\n" + "\n".join(f"{float(x)!r} {float(y)!r}" for x, y in points) + "\n")
    script = tmp_path / "eval.edp"
    script.write_text(f"""
mesh Th1 = readmesh("{run_p2}/mesh_body1.msh");
fespace Vh(Th1, [P2, P2]);
Vh [ux, uy];
{{ ifstream f("{run_p2}/u1.txt"); f >> ux[]; }}
ifstream pts("{listing}");
int n; pts >> n;
ofstream out("{tmp_path}/values.txt");
out.precision(17);
for (int i = 0; i < n; i++) {{
    real px, py; pts >> px; pts >> py;
    out << ux(px, py) << " " << uy(px, py) << endl;
}}
""")
    proc = run_freefem(script)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    exact = np.loadtxt(tmp_path / "values.txt")
    scale = np.abs(exact).max()
    assert np.abs(values - exact).max() < 1e-6 * scale, np.abs(values - exact).max() / scale
    # the parent mesh's edges: each midpoint is a point of the file, its value not the mean of the ends
    lines = (run_p2 / "mesh_body1.msh").read_text().split()
    nv, nt = int(lines[0]), int(lines[1])
    verts = np.array(lines[3:3 + 3 * nv], dtype=float).reshape(nv, 3)[:, :2]
    tris = np.array(lines[3 + 3 * nv:3 + 3 * nv + 4 * nt], dtype=int).reshape(nt, 4)[:, :3] - 1
    edges = np.unique(np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1), axis=0)

    def index_of(xy):
        d = ((points[None, :, :] - xy[:, None, :]) ** 2).sum(axis=2)
        k = d.argmin(axis=1)
        assert np.sqrt(d[np.arange(len(xy)), k]).max() < 1e-6, "a P2 node is not a point of body1.vtu"
        return k

    a, b = index_of(verts[edges[:, 0]]), index_of(verts[edges[:, 1]])
    m = index_of(0.5 * (verts[edges[:, 0]] + verts[edges[:, 1]]))
    curvature = np.abs(values[m] - 0.5 * (values[a] + values[b])).max()
    assert curvature > 1e-3 * scale, curvature / scale


def test_body_files_3d_same_names_and_p2_nodes(tmp_path):
    from conftest import run_cli

    out = tmp_path / "run"
    proc = run_cli("run", str(REPO / "cases/ball_on_slab.toml"), "--out", str(out), "--set", "mesh.nx=4",
                   "--set", "method.degree=2", "--set", "output.estimators=false")
    assert proc.returncode == 0, proc.stderr
    results = json.loads((out / "results.json").read_text())
    for body in (1, 2):
        mesh = read_body(out, body)
        assert BODY_FIELDS <= set(mesh.point_data), (body, list(mesh.point_data))
        assert len(mesh.points) == results[f"dofs_body{body}"] // 3, body
        if body == 1:
            assert BODY1_CELL_FIELDS <= set(mesh.cell_data)
    csv = pd.read_csv(out / "contact_pressure.csv")
    assert "pressure_recovered" in csv and csv.pressure_recovered.min() >= 0
    assert results["contact"]["max_pressure_recovered"] == pytest.approx(csv.pressure_recovered.max(), rel=1e-9)


def test_recovered_pressure_in_a_2d_run(run_p2):
    results = json.loads((run_p2 / "results.json").read_text())
    csv = pd.read_csv(run_p2 / "contact_pressure.csv")
    assert list(csv.columns[-1:]) == ["pressure_recovered"]
    assert csv.pressure.min() >= 0 and csv.pressure_recovered.min() >= 0
    contact = results["contact"]
    assert contact["max_pressure_recovered"] == pytest.approx(csv.pressure_recovered.max(), rel=1e-9)
    assert contact["max_pressure"] == pytest.approx(csv.pressure.max(), rel=1e-9)
    # the recovery spreads the pressure, it does not create force: its integral stays close to the raw one
    raw, recovered = (csv.weight * csv.pressure).sum(), (csv.weight * csv.pressure_recovered).sum()
    assert recovered == pytest.approx(raw, rel=0.1)
    assert contact["pressure_scatter_rms"] >= 0


def test_recovery_on_closed_form_pressures(tmp_path):
    """core/pressure_recovery.idp at the cut points of a line/plane and a circle/sphere: a linear
    pressure exactly, a Hertz-like parabola to O(h^2) (2D NX 20, 40, 80; 3D nx 10, 20)."""
    out = tmp_path / "check.json"
    proc = run_freefem("tools/pressure_recovery_check.edp", "-out", out)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    check = json.loads(out.read_text())
    for dim, levels in (("dim2", ("nx20", "nx40", "nx80")), ("dim3", ("nx10", "nx20"))):
        rows = [check[dim][level] for level in levels]
        assert rows[0]["linear_points"] > 0 and rows[0]["linear_max_error"] < 1e-10, (dim, rows[0])
        for coarse, fine in zip(rows, rows[1:]):
            assert coarse["hertz_points"] > 0 and fine["hertz_points"] > 0, dim
            order = np.log(coarse["hertz_max_error"] / fine["hertz_max_error"]) / np.log(
                coarse["h_max"] / fine["h_max"])
            assert order > 1.7, (dim, order, coarse, fine)
        assert rows[-1]["hertz_max_error"] < 0.1, (dim, rows[-1])


def test_foundation_fields_keep_the_p2_nodes(tmp_path):
    # The one-body foundation script writes its body-fitted mesh split once for P2, as
    # the two-body scripts' body files: one VTU point per P2 node, the same field names.
    from conftest import run_cli

    out = tmp_path / "run"
    proc = run_cli("run", str(REPO / "cases/patch_block.toml"), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    results = json.loads((out / "results.json").read_text())
    mesh = meshio.read(out / "fields.vtu")
    assert {"displacement", "von_mises"} <= set(mesh.point_data)
    assert len(mesh.points) == results["dofs"] // 2
    # the patch test's solution is affine: the split mesh's midpoints carry it exactly
    u = mesh.point_data["displacement"][:, :2]
    design = np.c_[np.ones(len(mesh.points)), mesh.points[:, :2]]
    fit, *_ = np.linalg.lstsq(design, u, rcond=None)
    assert np.abs(design @ fit - u).max() < 1e-9 * np.abs(u).max()


def test_the_summary_says_when_the_contact_zone_is_not_resolved(run_scene):
    """results.json contact.zone_elements = the zone's half-width over the mean h_K at the
    active points (the recovery's window); below zone_elements_needed (3) the summary
    warns. The disk on slab at NX = 20: 0.82 elements; at NX = 80: 3.62."""
    coarse = run_scene("cases/disk_on_slab.toml", "mesh.nx=20")
    fine = run_scene("cases/disk_on_slab.toml")
    for run, resolved in ((coarse, 0), (fine, 1)):
        c = run.results["contact"]
        lo, hi = c["active_extent"]["x"]
        assert c["zone_half_width"] == pytest.approx((hi - lo) / 2, rel=1e-12)
        assert c["zone_elements"] == pytest.approx(c["zone_half_width"] / c["zone_element_size"], rel=1e-12)
        assert c["zone_resolved"] == resolved and c["zone_elements_needed"] == 3
    # the structured mesh's h_K is the diagonal h sqrt(2) wherever the contact is
    assert coarse.results["contact"]["zone_element_size"] == pytest.approx(0.05 * 2 ** 0.5, rel=1e-12)
    assert 0.7 < coarse.results["contact"]["zone_elements"] < 0.9
    assert 3.4 < fine.results["contact"]["zone_elements"] < 3.8
    summary = [line for line in coarse.summary.splitlines()]
    assert summary[1].startswith("contact: peak pressure") and "(recovered;" in summary[1]
    assert summary[2].startswith("WARNING: the contact zone is not resolved")
    assert "WARNING" not in fine.summary


def test_an_adaptation_stopped_by_its_dof_budget_says_so(run_scene):
    run = run_scene("cases/disk_on_slab.toml", "mesh.nx=20", "method.degree=1", "adapt.steps=6",
                    "adapt.max_dofs=5000")
    adapt = run.results["adapt"]
    assert adapt["stop"] == "dof_budget" and adapt["steps_done"] < 6
    assert run.results["dofs"] * adapt["growth"] > adapt["max_dofs"]
    assert "stopped at its DOF budget (adapt.max_dofs = 5000" in run.summary
    full = run_scene("cases/disk_on_slab.toml", "mesh.nx=20", "method.degree=1", "adapt.steps=1")
    assert full.results["adapt"]["stop"] == "steps" and "stopped after every step asked" in full.summary


def flat_keys(tree, prefix=""):
    """The dotted paths of a results.json tree's leaves (a list is a leaf)."""
    keys = set()
    for key, value in tree.items():
        path = prefix + key
        keys |= flat_keys(value, path + ".") if isinstance(value, dict) else {path}
    return keys


def documented_one_dimension_keys(heading):
    """The keys docs/outputs.md lists in its table under `| only in 2D |` or `| only in 3D |`
    (case_a/b/c stands for case_a, case_b and case_c, body1/2 for body1 and body2: each
    alternative replaces as many last characters; an object covers its keys)."""
    text = (REPO / "docs" / "outputs.md").read_text()
    table = text[text.index(f"| only in {heading} |"):].split("\n\n")[0]
    keys = set()
    for row in table.splitlines()[2:]:
        for key in __import__("re").findall(r"`([^`]+)`", row.split("|")[1]):
            head, _, tail = key.rpartition(".")
            stem, *alternatives = tail.split("/")
            names = [stem] + [stem[:-len(a)] + a for a in alternatives]
            keys |= {f"{head}.{t}" if head else t for t in names}
    return keys


def covered(key, documented):
    return any(key == d or key.startswith(d + ".") for d in documented)


def test_2d_and_3d_results_have_the_same_keys_but_the_documented_ones(tmp_path):
    """The default 2D and 3D runs name every shared quantity alike; the keys only one
    dimension has are exactly those docs/outputs.md lists, each for a reason."""
    runs = {}
    for dim, script, nx in (("2D", "fd_contact_2d.edp", 20), ("3D", "fd_contact_3d.edp", 6)):
        out = tmp_path / dim
        proc = run_freefem(script, "-nx", nx, "-outdir", out)
        assert proc.returncode == 0, proc.stderr[-2000:]
        keys = flat_keys(json.loads((out / "results.json").read_text()))
        runs[dim] = {k for k in keys if not k.startswith("reactions.by_support.")}   # named for the scene's supports
    for dim, other in (("2D", "3D"), ("3D", "2D")):
        documented = documented_one_dimension_keys(dim)
        only = runs[dim] - runs[other]
        assert sorted(k for k in only if not covered(k, documented)) == []
        assert sorted(d for d in documented if not any(covered(k, {d}) for k in only)) == []
