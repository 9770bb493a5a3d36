"""Two-body fictitious-domain contact (disk on slab): physics checks on coarse meshes."""

import math

import meshio
import numpy as np
import pandas as pd
import pytest

from conftest import REPO, run_cli

DISK = "cases/disk_on_slab.toml"


def centre_y(run):
    return run.results["probes"]["centre"][1]


def disk24(module_scene, degree, theta):
    """The disk on slab at NX = 24 (shared by the tests of this module)."""
    return module_scene(DISK, "mesh.nx=24", f"method.degree={degree}", f"method.theta={theta}")


@pytest.mark.freefem
@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("theta", [1, 0, -1])
def test_disk_on_slab_converges_and_balances(module_scene, degree, theta):
    run = disk24(module_scene, degree, theta)
    r = run.results
    assert r["newton"]["iterations"] <= 8
    assert r["newton"]["residual"][-1] < 1e-6
    # the contact force carries the disk's weight (0, -0.1 |disk|)
    applied = r["contact"]["applied_force_body1"][1]
    assert applied == pytest.approx(-0.1 * r["measures"]["body1"], rel=1e-12)
    assert r["contact"]["force_balance_error"] < 1e-6
    assert 0 < r["contact"]["active_measure"] < 0.5 * r["contact"]["boundary_measure"]
    # the disk goes down by about 0.018 (NX = 80 P2 gives -0.01838)
    assert -0.025 < centre_y(run) < -0.014
    assert r["dofs"] == r["dofs_body1"] + r["dofs_body2"]
    assert r["dofs_body1"] < 0.5 * r["dofs"]          # unused background DOFs never enter


@pytest.mark.freefem
def test_solution_does_not_depend_on_theta(module_scene):
    """Every theta gives a consistent method: at NX = 24, P2 the centre for theta = 1
    and 0 lies within 8.5e-5 and 2.2e-4 (relative) of theta = -1's (measured); a
    wrong sign of theta in one of the contact terms moves theta = 1's by 7e-3."""
    reference = centre_y(disk24(module_scene, 2, -1))
    for theta, bound in ((1, 2e-4), (0, 5e-4)):
        assert abs(centre_y(disk24(module_scene, 2, theta)) / reference - 1) < bound, f"theta = {theta}"


@pytest.mark.freefem
def test_centre_against_the_nx320_reference(run_scene):
    """The default method at NX = 80 against the curved P2 NX = 320 reference of
    make curved-study (results/curved_convergence.csv, reference_uy): 2.3e-4 relative
    measured (the study's own NX = 80 row says the same)."""
    study = pd.read_csv(REPO / "results/curved_convergence.csv")
    reference = study.reference_uy.iloc[0]
    assert (study.reference_uy == reference).all()
    run = run_scene(DISK, "mesh.nx=80", "method.geometry='curved'", "output.vtu=false", "output.estimators=false",
                    "output.pressure_csv=false")
    assert abs(centre_y(run) / reference - 1) < 5e-4


@pytest.mark.freefem
@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("theta", [1, 0, -1])
def test_eta4_is_the_contact_residual_of_the_pressure_table(module_scene, degree, theta):
    """eta4^2 = sum over the contact points of h_K w (p + sigma_n)^2 (fd2d/estimators.idp),
    with p, sigma_n and w from contact_pressure.csv and h_K the one diameter of the
    uniform mesh's triangles: up to 2e-12 relative measured (the CSV's 12 digits)."""
    run = disk24(module_scene, degree, theta)
    s = run.contact_samples()
    expected = np.sqrt(run.results["h_max"] * np.sum(s.weight * (s.pressure + s.sigma_n) ** 2))
    assert run.results["estimator"]["eta4"] == pytest.approx(expected, rel=1e-11)


@pytest.mark.freefem
@pytest.mark.parametrize("theta", [1, 0, -1])
def test_eta1_of_p1_is_the_load_residual(module_scene, theta):
    """P1: div sigma = 0 on every element, so eta1^2 = sum h_K^2 |div sigma + f|^2 |K cap
    Omega_i| = h^2 |f|^2 |disk| (f = (0, -0.1) on the disk, 0 on the slab; one h_K on
    the uniform mesh): 2e-15 relative measured."""
    r = disk24(module_scene, 1, theta).results
    assert r["estimator"]["eta1"] == pytest.approx(r["h_max"] * 0.1 * math.sqrt(r["measures"]["body1"]), rel=1e-13)


@pytest.mark.freefem
def test_a_loose_tolerance_stops_on_the_same_solution(module_scene):
    """Newton stops only on an active set its last step kept: there the semi-smooth
    Newton iterate is the discrete solution, so newton_tol = 1e-2 gives the default's
    solution to the last digit (measured: equal), although the residual of step 2
    (2.3e-3, active set still moving) is already below it. allow_unbalanced keeps a
    run that would stop early, to be seen here in its numbers rather than only
    refused by the balance gate."""
    tight = disk24(module_scene, 2, -1)
    loose = module_scene(DISK, "mesh.nx=24", "method.degree=2", "method.theta=-1", "solver.newton_tol=1e-2",
                         "solver.allow_unbalanced=true")
    n = loose.results["newton"]
    assert n["residual"][1] < 1e-2 and n["changed_measure"][1] > 0   # the case this test is about
    assert n["iterations"] == tight.results["newton"]["iterations"]
    assert centre_y(loose) == pytest.approx(centre_y(tight), rel=1e-12)
    assert loose.results["balance"]["balance_error"] < 1e-6


@pytest.mark.freefem
def test_round_off_floor_needs_two_stable_steps(run_scene):
    """Below the direct solver's round-off (newton_tol 1e-15, residual 2e-14) Newton
    stops on the round-off floor, after two steps on one active set: a looser
    tolerance would stop one step earlier and call it 'tolerance' (conftest's check
    of every run's stop asserts which rule held)."""
    run = run_scene(DISK, "mesh.nx=24", "method.degree=1", "solver.newton_tol=1e-15", "output.vtu=false",
                    "output.estimators=false", "output.pressure_csv=false")
    n = run.results["newton"]
    assert n["converged_by"] == "roundoff_floor"
    assert 1e-15 < n["residual"][-1] < 1e-12
    assert n["changed_measure"][-2:] == [0, 0]


@pytest.mark.freefem
def test_slab_interface_on_mesh_edges_is_handled(run_scene):
    # nx = 40: y = -0.25 lies on grid lines; nx = 42: it cuts the elements.
    on_edges = run_scene(DISK, "mesh.nx=40")
    cutting = run_scene(DISK, "mesh.nx=42")
    assert on_edges.results["measures"]["body2"] == pytest.approx(0.25, rel=1e-9)
    assert cutting.results["measures"]["body2"] == pytest.approx(0.25, rel=1e-9)
    assert centre_y(on_edges) == pytest.approx(centre_y(cutting), rel=0.01)


@pytest.mark.freefem
def test_nitsche_dirichlet_line_reproduces_strong_bottom(run_scene):
    strong = run_scene(DISK, "mesh.nx=30")
    nitsche = run_scene(DISK, "mesh.nx=30", "body2.bottom_line=[-0.5, 0.0]")
    assert nitsche.results["supports"]["nitsche_hold_points_body2"] > 0
    assert strong.results["supports"]["nitsche_hold_points_body2"] == 0
    assert centre_y(nitsche) == pytest.approx(centre_y(strong), rel=1e-5)   # measured 2.5e-6


@pytest.mark.freefem
def test_tilted_cut_dirichlet_scene(run_scene):
    run = run_scene("cases/disk_on_tilted_slab.toml", "mesh.nx=30")
    r = run.results
    assert r["supports"]["nitsche_hold_points_body2"] > 0
    assert r["cut"]["dirichlet_case_a"] + r["cut"]["dirichlet_case_b"] + r["cut"]["dirichlet_case_c"] > 0
    assert r["measures"]["body2"] == pytest.approx(0.19, rel=1e-9)   # between y = -0.44 + 0.1x and -0.25
    assert r["contact"]["force_balance_error"] < 1e-6


@pytest.mark.freefem
@pytest.mark.parametrize("stabilization", ["neighbour", "ghost"])
def test_stabilizations_agree_with_plain_method(run_scene, module_scene, stabilization):
    plain = module_scene(DISK, "mesh.nx=30")
    stab = run_scene(DISK, "mesh.nx=30", f"method.stabilization='{stabilization}'")
    cut = stab.results["cut"]
    assert cut["stabilization"] == stabilization
    assert cut["case_a"] + cut["case_b"] + cut["case_c"] > 0
    if stabilization == "neighbour":
        assert cut["case_b"] > 0 and cut["case_c"] == 0
        # the rule's cases against the cut ratios the run wrote (body1.vtu: P2, each
        # element split in four): case a is every cut element with ratio >= rho
        vtu = meshio.read(stab.folder / "body1.vtu")
        ratio = np.ravel(next(data for block, data in zip(vtu.cells, vtu.cell_data["cut_ratio"])
                              if block.type == "triangle"))
        assert cut["case_a"] == ((ratio >= cut["rho"]) & (ratio < 1)).sum() / 4
        assert cut["case_b"] + cut["case_c"] == (ratio < cut["rho"]).sum() / 4
    else:
        # the ghost penalty controls the badly cut elements' rows: the spread of the
        # Newton matrix's diagonal (a lower bound of its condition number) drops from
        # 7.0e3 to 1.5e2 here (measured)
        spread = stab.results["linear_solver"]["diagonal_spread_max"]
        assert spread < plain.results["linear_solver"]["diagonal_spread_max"] / 20
    assert centre_y(stab) == pytest.approx(centre_y(plain), rel=0.02)


@pytest.mark.freefem
def test_auto_stabilization_keeps_theta1_coercive(run_scene, tmp_path):
    # theta = 1 at gamma0 = 1/10, NX = 80, P1 cut geometry: without stabilization the
    # symmetric method is not coercive on this cut mesh (Newton cycles: exit 3 with the
    # coercivity hint); the default (auto = ghost penalty for theta > 0) converges. The
    # curved geometry cuts the same elements differently and happens to converge here.
    settings = ["mesh.nx=80", "method.geometry='p1'", "method.theta=1", "method.gamma0=0.1",
                "output.estimators=false", "output.vtu=false", "output.pressure_csv=false"]
    auto = run_scene(DISK, *settings)
    assert auto.results["cut"]["stabilization"] == "ghost"
    assert auto.results["newton"]["iterations"] <= 8
    assert auto.results["contact"]["force_balance_error"] < 1e-6
    plain = run_cli("run", DISK, "--out", str(tmp_path / "plain"), "--set",
                    " ".join(settings + ["method.stabilization='none'"]))
    assert plain.returncode == 3, plain.stderr
    assert "coercivity" in plain.stderr
    assert not (tmp_path / "plain" / "results.json").exists()


@pytest.mark.freefem
def test_auto_stabilization_is_none_for_nonpositive_theta(run_scene):
    run = run_scene(DISK, "mesh.nx=20", "method.theta=0", "output.estimators=false")
    assert run.results["cut"]["stabilization"] == "none"
    assert "estimator" not in run.results


@pytest.mark.parametrize("override, key", [
    ("body1.centre=[3.0, 0.4]", "body1"),                      # misses the box
    ("body1.radius=0.6", "body1"),                             # reaches into the slab
    ("body2.top=0.7", "body2.top"),
    ("body2.bottom_line=[-0.6, 0.0]", "body2.bottom_line"),
    ("body1.centre=[0.0, -0.1]", "body1"),                     # overlaps the slab
    ("method.stabilization='magic'", "method.stabilization"),
    ("rigid.fix_x_points=[0.0, 0.0, 0.4, 0.4]", "rigid.fix_x_points"),
    ("mesh.nx=1", "mesh.nx"),
])
def test_bad_fd_geometry_is_rejected(override, key):
    proc = run_cli("run", DISK, "--set", override)
    assert proc.returncode == 2
    assert key in proc.stderr and DISK in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.freefem
@pytest.mark.parametrize("stabilization", ["none", "neighbour", "ghost"])
def test_sliver_cuts_are_dropped_not_fatal(run_scene, stabilization):
    # Slab top 1e-6 h above a grid line: cut ratios ~1e-13 (the crash case of a plain cut space).
    nx, shift = 20, 1e-6 / 20
    plain = run_scene(DISK, f"mesh.nx={nx}", f"method.stabilization='{stabilization}'")
    sliver = run_scene(DISK, f"mesh.nx={nx}", f"method.stabilization='{stabilization}'",
                       f"body1.centre=[0.0, {shift!r}]", f"body2.top={-0.25 + shift!r}",
                       f"rigid.fix_x_points=[0.0, {shift!r}, 0.0, {0.1 + shift!r}]")
    cut = sliver.results["cut"]
    assert min(cut["min_ratio_body1"], cut["min_ratio_body2"]) < 1e-9
    assert cut["dropped_body1"] + cut["dropped_body2"] > 0
    assert cut["extended_max_distance_over_h"] < 1e-3
    assert sliver.results["newton"]["residual"][-1] < 1e-8
    assert sliver.results["newton"]["iterations"] <= plain.results["newton"]["iterations"] + 2
    assert centre_y(sliver) == pytest.approx(centre_y(plain), rel=0.02)
    assert sliver.results["measures"]["body2"] == pytest.approx(0.25 + shift, rel=1e-9)
