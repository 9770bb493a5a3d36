"""One body on a rigid foundation, body-fitted mesh: exactness, separation, complementarity."""

import json

import numpy as np
import pytest

from conftest import relative_max_error, run_freefem
from driver.runner import freefem_env

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)


@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("theta", [1, 0, -1])
def test_patch_block_is_exact(run_scene, degree, theta):
    # p = 10, E = 1e3, nu = 0.3 (cases/patch_block.toml), plane strain.
    run = run_scene("cases/patch_block.toml", f"method.degree={degree}", f"method.theta={theta}")
    p, E, nu = 10.0, 1.0e3, 0.3
    xy, u = run.points_and_displacement()
    exact = np.column_stack([p * nu * (1 + nu) / E * xy[:, 0], -p * (1 - nu**2) / E * xy[:, 1]])
    assert relative_max_error(u, exact) < 1e-9
    assert run.results["contact"]["active_measure"] == pytest.approx(1.0, abs=1e-12)
    assert run.results["contact"]["force_on_body"][1] == pytest.approx(p, rel=1e-9)


LIFT = ["loads.body_force=[0.0, 1.0e4]"]     # pulled upwards, the square leaves the foundation
FREE_BOTTOM = "boundary.3.type='free'"


@pytest.mark.parametrize("degree", [1, 2])
def test_separation_matches_problem_without_contact(run_scene, degree):
    # With theta = 0 an inactive contact boundary adds nothing to the system.
    settings = [*LIFT, "mesh.nx=8", f"method.degree={degree}", "method.theta=0"]
    with_contact = run_scene("cases/square_slip_separation.toml", *settings)
    without = run_scene("cases/square_slip_separation.toml", *settings, FREE_BOTTOM)
    samples = with_contact.contact_samples()
    assert (samples["pressure"] == 0).all()
    assert with_contact.results["contact"]["active_measure"] == 0
    _, u_contact = with_contact.points_and_displacement()
    _, u_free = without.points_and_displacement()
    assert relative_max_error(u_contact, u_free) < 1e-12


# theta = 1 needs gamma0 small enough for coercivity: about 0.25 on this mesh family
# (gamma = gamma0 h_K / E).
@pytest.mark.parametrize("theta, gamma0", [(1, 0.1), (-1, 1.0)])
def test_separation_with_theta_converges_to_problem_without_contact(run_scene, theta, gamma0):
    # For theta != 0 the term -theta gamma sigma_n(u) sigma_n(v) stays on the separated
    # boundary: consistent (sigma_n = 0 there), so the difference is a discretization
    # error that must shrink with h, with zero pressure at every size.
    differences = []
    for nx in (8, 16, 32):
        settings = [*LIFT, f"mesh.nx={nx}", "method.degree=1", f"method.theta={theta}",
                    f"method.gamma0={gamma0}"]
        with_contact = run_scene("cases/square_slip_separation.toml", *settings)
        without = run_scene("cases/square_slip_separation.toml", *settings, FREE_BOTTOM)
        assert (with_contact.contact_samples()["pressure"] == 0).all()
        differences.append(relative_max_error(with_contact.points_and_displacement()[1],
                                              without.points_and_displacement()[1]))
    assert differences[0] < 0.05
    assert differences[2] < differences[1] / 1.5 < differences[0] / 1.5**2


def test_complementarity_on_square_scene(run_scene):
    run = run_scene("cases/square_slip_separation.toml")   # P2, h = 1/32, theta = -1
    s = run.contact_samples()
    _, u = run.points_and_displacement()
    u_scale = np.abs(u).max()
    p_scale = s["pressure"].max()
    assert (s["pressure"] >= 0).all()      # positive in compression, as in the two-body scripts
    # Nitsche enforces the gap condition weakly: penetration is O(gamma |p - sigma_n|).
    assert s["open_gap"].min() >= -1e-3 * u_scale
    assert (s["pressure"] * s["open_gap"]).abs().max() <= 1e-3 * p_scale * u_scale
    # The bottom stays in contact near the clamp and separates beyond about x = 0.5.
    box = run.results["contact"]["active_box"]
    assert 0.0 <= box[0] < 0.1 and 0.4 < box[2] < 0.6


def test_gmsh_mesh_agrees_with_box_mesh(run_scene):
    box = run_scene("cases/square_slip_separation.toml", "mesh.nx=16")
    gmsh = run_scene("cases/square_slip_separation_gmsh.toml", "mesh.nx=16")
    assert gmsh.results["elements"] != box.results["elements"]     # really another mesh
    force_box = box.results["contact"]["force_on_body"][1]
    force_gmsh = gmsh.results["contact"]["force_on_body"][1]
    assert force_gmsh == pytest.approx(force_box, rel=0.02)
    assert gmsh.results["norms"]["h1"] == pytest.approx(box.results["norms"]["h1"], rel=0.01)


def test_the_blas_runs_on_one_thread_whatever_the_environment_says(tmp_path):
    # Debian's threaded OpenBLAS would take OPENBLAS_NUM_THREADS threads under UMFPACK,
    # and two threads change the last digits of the foundation scene's results
    results = {}
    for threads in ("1", "2"):
        out = tmp_path / f"threads{threads}"
        proc = run_freefem("contact_foundation_2d.edp", "-nx", 40, "-outdir", out,
                           env=dict(freefem_env(), OPENBLAS_NUM_THREADS=threads))
        assert proc.returncode == 0, proc.stderr[-2000:]
        results[threads] = json.loads((out / "results.json").read_text())
    for key in ("norms", "estimator", "contact"):
        assert results["1"][key] == results["2"][key]
