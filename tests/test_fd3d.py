"""Two-body fictitious-domain contact in 3D (ball on slab): physics checks on coarse meshes."""

import subprocess

import meshio
import numpy as np
import pandas as pd
import pytest

from conftest import REPO, run_cli, run_freefem
from driver.runner import freefem_env

BALL = "cases/ball_on_slab.toml"


def centre_z(run):
    return run.results["probes"]["centre"][2]


def ball8(module_scene, theta):
    """The ball on slab at nx = 8, P1 (shared by the tests of this module)."""
    return module_scene(BALL, "mesh.nx=8", f"method.theta={theta}")


@pytest.mark.freefem
@pytest.mark.parametrize("theta", [1, 0, -1])
def test_ball_on_slab_converges_and_balances(module_scene, theta):
    run = ball8(module_scene, theta)
    r = run.results
    assert r["dim"] == 3 and r["degree"] == 1
    assert r["newton"]["converged_by"] in ("tolerance", "roundoff_floor")
    assert r["newton"]["iterations"] <= 8
    assert r["newton"]["residual"][-1] < 1e-8
    # equilibrium: the contact force on the ball carries its weight (0, 0, -0.1 |ball|)
    applied = r["contact"]["applied_force_body1"]
    assert applied[2] == pytest.approx(-0.1 * r["measures"]["body1"], rel=1e-12)
    # the contact force against the applied load, computed apart from the assembly:
    # 3.0e-8 measured (what the mass term carries)
    force = r["contact"]["force_on_body1"]
    assert force[2] == pytest.approx(-applied[2], rel=1e-7)
    assert r["contact"]["force_balance_error"] < 1e-7
    assert r["balance"]["balance_error"] < 1e-7
    # the curved cells integrate the exact ball (7.7e-9 measured, the volume rules'
    # tolerance); slab exact
    assert r["measures"]["body1"] == pytest.approx(4 / 3 * np.pi * 0.25 ** 3, rel=2e-8)
    assert r["measures"]["body2"] == pytest.approx(0.25, rel=1e-8)
    assert 0 < r["contact"]["active_measure"] < 0.1 * r["contact"]["boundary_measure"]
    assert -0.05 < centre_z(run) < -0.02
    assert r["dofs"] == r["dofs_body1"] + r["dofs_body2"]
    assert r["dofs_body1"] < 0.5 * r["dofs"]      # unused background DOFs never enter


@pytest.mark.freefem
def test_solution_does_not_depend_on_theta(module_scene):
    """Every theta gives a consistent method: the centres for theta = 1 and 0 approach
    theta = -1's as the mesh is refined. The contact zone (a point on the sphere) is
    narrower than an element at these sizes, so the gap is a discretization error:
    theta = 1 lies 7.4e-3 from theta = -1 at nx = 8, 3.4e-3 at nx = 12 (relative,
    measured), theta = 0 half way (3.4e-3, 1.7e-3)."""
    def gaps(nx):
        def centre(theta):   # the same runs as ball8's at nx = 8
            return centre_z(module_scene(BALL, f"mesh.nx={nx}", f"method.theta={theta}"))
        return {theta: abs(centre(theta) / centre(-1) - 1) for theta in (1, 0)}
    coarse, fine = gaps(8), gaps(12)
    assert coarse[1] < 9e-3 and fine[1] < 4.2e-3
    assert coarse[0] < 4.5e-3 and fine[0] < 2.1e-3
    for theta in (1, 0):   # a ratio of 2.2 measured for both
        assert fine[theta] < coarse[theta] / 1.8, f"theta = {theta}"


@pytest.mark.freefem
@pytest.mark.parametrize("theta", [1, 0, -1])
def test_eta4_is_the_contact_residual_of_the_pressure_table(module_scene, theta):
    """eta4^2 = sum over the contact points of h_K w (p + sigma_n)^2 (fd3d/estimators.idp),
    with p, sigma_n and w from contact_pressure.csv and h_K the one diameter of the
    uniform mesh's tetrahedra: up to 1.3e-12 relative measured (the CSV's 12 digits)."""
    run = ball8(module_scene, theta)
    s = run.contact_samples()
    expected = np.sqrt(run.results["h_max"] * np.sum(s.weight * (s.pressure + s.sigma_n) ** 2))
    assert run.results["estimator"]["eta4"] == pytest.approx(expected, rel=1e-11)


@pytest.mark.freefem
def test_gap_is_the_height_above_the_slab(module_scene):
    """The slab {z < -0.25} is flat: a contact point's gap is its height above the slab
    and its projection the point below it (contact_pressure.csv: 5e-13 measured, the
    CSV's 12 digits on gaps up to 0.5)."""
    s = ball8(module_scene, -1).contact_samples()
    assert np.abs(s.gap - (s.z + 0.25)).max() < 2e-12
    assert np.abs(s.proj_z + 0.25).max() < 1e-12
    assert np.abs(s.proj_x - s.x).max() < 1e-12 and np.abs(s.proj_y - s.y).max() < 1e-12


@pytest.mark.freefem
def test_slab_top_cutting_the_elements_and_neighbour_stabilization(run_scene):
    # nx = 10: z = -0.25 cuts the cells (nx = 8: it lies on a grid plane)
    plain = run_scene(BALL, "mesh.nx=10")
    stab = run_scene(BALL, "mesh.nx=10", "method.stabilization='neighbour'")
    assert plain.results["measures"]["body2"] == pytest.approx(0.25, rel=1e-8)
    assert plain.results["cut"]["cut_elements_body2"] > 0
    cut = stab.results["cut"]
    # face neighbours (two rings) hold a well cut element for almost every badly cut one
    assert cut["case_b"] > 0 and cut["case_c"] < 0.1 * (cut["case_a"] + cut["case_b"] + cut["case_c"])
    assert stab.results["contact"]["force_balance_error"] < 0.01
    assert centre_z(stab) == pytest.approx(centre_z(plain), rel=0.05)


@pytest.mark.freefem
def test_sliver_cuts_are_dropped_and_the_smallest_kept_ratio_reported(run_scene):
    # Slab top 1e-6 h above the grid plane z = -0.25 (nx = 8): cut ratios ~1e-6
    nx, shift = 8, 1e-6 / 8
    sliver = run_scene(BALL, f"mesh.nx={nx}", f"body1.centre=[0.0, 0.0, {shift!r}]", f"body2.top={-0.25 + shift!r}")
    cut = sliver.results["cut"]
    assert cut["min_ratio_body2"] < 2e-6 and cut["dropped_body2"] > 0
    # the kept elements' smallest ratio lies above the sliver rule's bound, the rest are dropped
    assert cut["drop_ratio"] < cut["min_kept_ratio_body2"] <= 1
    assert cut["min_ratio_body1"] <= cut["min_kept_ratio_body1"] <= 1
    assert sliver.results["newton"]["residual"][-1] < 1e-8
    assert sliver.results["measures"]["body2"] == pytest.approx(0.25 + shift, rel=1e-9)


@pytest.mark.freefem
def test_outputs_are_readable(module_scene):
    run = ball8(module_scene, -1)
    ball = meshio.read(run.folder / "body1.vtu")
    assert {"displacement", "von_mises"} <= set(ball.point_data)
    assert "contact_pressure" in ball.cell_data
    cut = pd.read_csv(run.folder / "centre_cut.csv")
    assert set(cut["body"]) == {1, 2}
    pressure = pd.read_csv(run.folder / "contact_pressure.csv")
    assert (pressure["pressure"] >= 0).all() and (pressure["pressure"] > 0).any()   # positive in compression


@pytest.mark.parametrize("override, key", [
    ("body1.centre=[3.0, 0.0, 0.0]", "body1"),                 # misses the box
    ("body1.centre=[0.0, 0.0, -0.1]", "body1"),                # overlaps the slab
    ("body2.top=0.7", "body2.top"),
    ("rigid.fix_y_point=[0.0, 0.0, 0.05]", "rigid.fix_y_point"),
    ("method.stabilization='penalty'", "method.stabilization"),
    ("method.ghost_gamma=-1", "method.ghost_gamma"),
])
def test_bad_3d_input_is_rejected(override, key):
    proc = run_cli("run", BALL, "--set", override)
    assert proc.returncode == 2
    assert key in proc.stderr and BALL in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.freefem
def test_freefem_script_rejects_a_ball_outside_the_box(tmp_path):
    proc = subprocess.run(["FreeFem++", "-nw", "-v", "0", "freefem/fd_contact_3d.edp", "-Ddegree=1",
                           "-ball_cz", "0.4", "-outdir", str(tmp_path)],
                          cwd=REPO, env=freefem_env(), capture_output=True, text=True)
    assert proc.returncode == 2
    assert "INPUT ERROR" in proc.stdout + proc.stderr


@pytest.mark.freefem
def test_error_routine_measures_a_known_shift(run_scene, tmp_path):
    # A saved P2 run against itself shifted by a constant c: |c| |Omega_i|^(1/2) in L2 and H1.
    run = run_scene(BALL, "mesh.nx=4", "method.degree=2", "output.save_solution=true", "output.vtu=false")
    out = tmp_path / "errors.json"
    proc = subprocess.run(["FreeFem++", "-nw", "-v", "0", "freefem/tools/fd_error_3d.edp", "-ref", str(run.folder),
                           "-run", str(run.folder), "-shift_z", "1e-3", "-out", str(out)],
                          cwd=REPO, env=freefem_env(), capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    import json
    err = json.loads(out.read_text())
    for body in ("body1", "body2"):
        expected = 1e-3 * err[body]["volume_ref"] ** 0.5
        assert err[body]["l2_abs"] == pytest.approx(expected, rel=1e-9)
        assert err[body]["h1_abs"] == pytest.approx(expected, rel=1e-9)
    assert err["body1"]["volume_ref"] == pytest.approx(run.results["measures"]["body1"], rel=1e-9)


@pytest.mark.freefem
def test_neighbour_stabilization_rescues_theta_one(run_scene, tmp_path):
    # P2, theta = 1, h = 1/6 without stabilization: Newton does not converge in 30
    # iterations (badly cut elements spoil coercivity, results/fd3d_convergence.csv;
    # last residual 1.0); the neighbour stress (R_rho) restores it.
    # On the P1 geometry: the curved geometry cuts this mesh's elements less badly and
    # converges without stabilization at nx = 5 to 9.
    settings = ["mesh.nx=6", "method.degree=2", "method.theta=1", "output.vtu=false", "method.geometry='p1'"]
    plain = run_cli("run", BALL, "--out", str(tmp_path / "plain"), "--set",
                    " ".join(settings + ["method.stabilization='none'"]))
    assert plain.returncode == 3, plain.stderr
    assert "did not converge" in plain.stderr and "coercivity" in plain.stderr
    assert not (tmp_path / "plain" / "results.json").exists()
    run = run_scene(BALL, *settings, "method.stabilization='neighbour'")
    r = run.results
    assert r["newton"]["iterations"] <= 6
    assert r["contact"]["force_balance_error"] < 1e-6
    assert r["cut"]["case_b"] > 0


GHOST_TOOL_BOUNDS = {
    # measured (nx 6): polynomial |G u| / (|G| |u|) 1.2e-16 (P1), 1.6e-16 (P2); kink relative
    # errors 1.5e-15 (P1), 3.4e-13 and 1.6e-14 (P2, first and second derivative); the free
    # block's condition with the ghost penalty over eps = 0.5 .. 1e-3: 278 .. 1159 (P1),
    # 1.6e4 .. 4.4e4 (P2); without it 3.3e4 .. 3.3e7 (P1), 7.1e3 .. 6.3e10 (P2)
    1: dict(polynomial=1e-15, kink=1e-14, ghost_condition=1.5e3, plain_condition_at_1e_2=1e7),
    2: dict(polynomial=1e-15, kink=1e-12, ghost_condition=6e4, plain_condition_at_1e_2=1e10),
}


@pytest.mark.freefem
@pytest.mark.parametrize("degree", [1, 2])
def test_ghost_penalty_3d_matrix_and_conditioning(tmp_path, degree):
    # freefem/tools/ghost_penalty_check_3d.edp: the penalty matrix on its own against
    # fields whose jumps are known (zero for a global polynomial of degree k; a kink
    # across a grid plane below the cut layer of a slab), its face count, and the
    # condition of a slab's cut stiffness as its top nears a grid plane (eps h above it).
    out = tmp_path / "ghost3d.csv"
    proc = run_freefem("tools/ghost_penalty_check_3d.edp", f"-Ddegree={degree}", "-nx", 6, "-out", out)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = pd.read_csv(out)
    bounds = GHOST_TOOL_BOUNDS[degree]
    check = rows.set_index("check")
    assert check.loc["polynomial", "value"] < bounds["polynomial"]
    assert check.loc["faces", "value"] == check.loc["faces", "expected"] == 12 * 6**2 - 4 * 6
    kinks = ["kink_first", "kink_second"] if degree == 2 else ["kink_first"]
    for kink in kinks:
        value, exact = check.loc[kink, "value"], check.loc[kink, "expected"]
        assert abs(value / exact - 1) < bounds["kink"], kink
    cond = rows[rows["check"] == "condition"].pivot(index="eps", columns="stabilization", values="value")
    print(cond)
    assert (cond["ghost"] < bounds["ghost_condition"]).all()
    assert cond.loc[1e-2, "none"] > bounds["plain_condition_at_1e_2"]
    assert (cond.loc[[1e-2, 1e-3], "ghost"] < cond.loc[[1e-2, 1e-3], "none"] / 1e3).all()


@pytest.mark.freefem
def test_ghost_penalty_rescues_theta_one(run_scene, module_scene):
    # P2, theta = 1, h = 1/6, on the P1 geometry: without stabilization Newton does not
    # converge (test_neighbour_stabilization_rescues_theta_one); the 3D ghost penalty
    # restores it. Measured: 3 iterations, force balance 3.4e-8, 408 penalized faces per body,
    # the centre within 0.76 % of theta = -1's with the same penalty, the Newton
    # matrix's diagonal spread 7.2e6 (neighbour: 7.1e12, its pins' penalty over the
    # sliver rows).
    settings = ["mesh.nx=6", "method.degree=2", "output.vtu=false", "output.estimators=false",
                "method.stabilization='ghost'", "method.geometry='p1'"]
    run = run_scene(BALL, *settings, "method.theta=1")
    r = run.results
    assert r["cut"]["stabilization"] == "ghost" and r["cut"]["ghost_gamma"] == 0.01
    assert r["cut"]["ghost_faces_body1"] > 0 and r["cut"]["ghost_faces_body2"] > 0
    assert r["newton"]["iterations"] <= 3
    assert r["contact"]["force_balance_error"] < 1e-7
    assert r["linear_solver"]["diagonal_spread_max"] < 2e7
    symmetric = run_scene(BALL, *settings, "method.theta=-1")
    assert centre_z(run) == pytest.approx(centre_z(symmetric), rel=0.015)


def error_tool(ref, run, tmp_path, *extra):
    import json
    out = tmp_path / f"errors{len(list(tmp_path.glob('errors*.json')))}.json"
    proc = subprocess.run(["FreeFem++", "-nw", "-v", "0", "freefem/tools/fd_error_3d.edp", "-ref", str(ref),
                           "-run", str(run), "-out", str(out), *extra],
                          cwd=REPO, env=freefem_env(), capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return json.loads(out.read_text())


@pytest.mark.freefem
def test_error_routine_quadrature_path_matches_the_nested_one(run_scene, tmp_path):
    # Non-nested meshes (a graded reference) integrate the error with the coarse field
    # evaluated at the reference quadrature points (lifted to the coarse background,
    # extended next to the body); on nested meshes that path must give the exact
    # nested figures, and on the run itself shifted by c exactly |c| |Omega_i|^(1/2).
    # On the P1 geometry, whose coarse ball lies inside the fine one, so that both paths
    # extend the coarse field (the curved balls coincide).
    p1 = "method.geometry='p1'"
    ref = run_scene(BALL, "mesh.nx=8", "method.degree=2", "output.save_solution=true", "output.vtu=false", p1)
    coarse = run_scene(BALL, "mesh.nx=4", "output.save_solution=true", "output.vtu=false", p1)
    nested = error_tool(ref.folder, coarse.folder, tmp_path)
    direct = error_tool(ref.folder, coarse.folder, tmp_path, "-direct", "1")
    assert nested["nested"] == 1 and direct["nested"] == 0
    # the two paths extend the coarse field beyond its body differently (per
    # reference node / per outside element): equal up to that thin shell
    assert nested["body1"]["nodes_read_by_extension"] > 0 and direct["body1"]["elements_extended"] > 0
    # measured: 9.0e-5 on the ball, 1e-15 on the slab
    for body in ("body1", "body2"):
        for key in ("l2_rel", "h1_rel"):
            assert direct[body][key] == pytest.approx(nested[body][key], rel=3e-4)
        assert 0.01 < direct[body]["h1_rel"] < 2
    shifted = error_tool(ref.folder, ref.folder, tmp_path, "-direct", "1", "-shift_x", "2e-3")
    for body in ("body1", "body2"):   # measured: 2e-14
        expected = 2e-3 * shifted[body]["volume_ref"] ** 0.5
        assert shifted[body]["l2_abs"] == pytest.approx(expected, rel=1e-12)
        assert shifted[body]["h1_abs"] == pytest.approx(expected, rel=1e-12)


@pytest.mark.freefem
def test_graded_background_solves_and_its_errors_are_measured(run_scene, tmp_path):
    # tetgen refines cube(5) toward the contact point (as the references' meshes):
    # every contact point must be read on the body spaces (FreeFEM's location in a
    # submesh missed some; evaluation goes through the background, and slivers
    # find a kept element among larger vertex stars), the solve balances, and the
    # error tool takes the non-nested pair against a uniform run.
    graded = ("mesh.nx=5", "mesh.grade_h=0.06", "mesh.grade_radius=0.08", "output.save_solution=true",
              "output.vtu=false", "output.estimators=false")
    p1 = run_scene(BALL, *graded)
    ref = run_scene(BALL, *graded, "method.degree=2")
    uniform = run_scene(BALL, "mesh.nx=6", "output.save_solution=true", "output.vtu=false")
    for run in (p1, ref):
        r = run.results
        assert r["grade_h"] == pytest.approx(0.06)
        assert r["elements"] > 4 * 6 * 5 ** 3
        assert r["newton"]["converged_by"] in ("tolerance", "roundoff_floor")
        assert r["contact"]["force_balance_error"] < 1e-4
        # the contact zone is narrower than an element of the uniform mesh: the graded
        # runs resolve it and sink further (1.41 and 1.61 times the uniform run's centre,
        # measured; a uniform nx = 16 run: 1.38)
        assert 1.2 < centre_z(run) / centre_z(uniform) < 1.8
    err = error_tool(ref.folder, uniform.folder, tmp_path)
    assert err["nested"] == 0 and err["body1"]["elements_extended"] > 0
    for body in ("body1", "body2"):
        assert 0.01 < err[body]["h1_rel"] < 1.5 and err[body]["l2_rel"] < err[body]["h1_rel"]


@pytest.mark.freefem
def test_predictor_hands_over_from_above(run_scene):
    # P2, nx = 10: the gap-prefix predictor climbs until a trial set is larger than
    # the set its solution asks for (0.0288 against the final 0.0235, measured), then
    # semi-smooth Newton settles it within 0.5 % in three steps. A secant below the
    # fixed point took 8 steps and 5 factorizations on this mesh (P1 geometry, its set
    # overshot to 0.0311 against 0.0185; freefem/fd_contact_3d.edp -Ddegree=2 -nx 10
    # at commit ab28073).
    run = run_scene(BALL, "mesh.nx=10", "method.degree=2", "output.estimators=false", "output.vtu=false")
    n = run.results["newton"]
    assert n["converged_by"] == "tolerance"
    assert n["iterations"] <= 5 and n["factorizations"] <= 2
    final = n["active_measure"][-1]
    assert n["active_measure"][0] > 1.15 * final
    assert all(abs(a / final - 1) < 0.01 for a in n["active_measure"][1:])
    assert final == pytest.approx(0.023523, rel=1e-4)
