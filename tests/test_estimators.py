"""Residual estimators (fitted mesh) vanish where they must; adaptation lowers eta."""

import json

import pytest

from conftest import run_freefem

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)


def test_estimators_vanish_on_the_patch_test(run_scene):
    # Affine exact solution in the space: every residual is zero up to round-off.
    run = run_scene("cases/patch_block.toml")
    est = run.results["estimator"]
    p, area = 10.0, 1.0
    scale = p * area ** 0.5          # size of a stress residual over the domain
    for key in ("eta1", "eta2", "eta3", "eta4", "eta", "zeta"):
        assert est[key] <= 1e-9 * scale, key


def test_contact_estimators_vanish_without_contact_boundary(run_scene):
    run = run_scene("cases/square_slip_separation.toml", "mesh.nx=8", "boundary.3.type='free'",
                    "loads.body_force=[0.0, 0.0]")
    est = run.results["estimator"]
    assert est["eta3"] == 0 and est["eta4"] == 0
    assert est["eta1"] > 0 and est["eta2"] > 0      # the bulk residuals do not vanish


def test_adaptive_loop_lowers_eta(run_scene):
    run = run_scene("cases/square_slip_separation.toml", "mesh.nx=8", "adapt.steps=4", "output.vtu=false")
    steps = run.results["steps"]
    assert len(steps["eta"]) == 5
    assert all(b < a for a, b in zip(steps["eta"], steps["eta"][1:]))
    assert steps["eta"][-1] < 0.5 * steps["eta"][0]
    assert all(b > a for a, b in zip(steps["dofs"], steps["dofs"][1:]))
    # bounded per-step refinement: the element count at most ~maxRefine^2 times larger
    assert all(b < 16 * a for a, b in zip(steps["elements"], steps["elements"][1:]))


def test_error_routine_against_itself_and_a_known_shift(run_scene, tmp_path):
    ref = run_scene("cases/square_slip_separation.toml", "mesh.nx=8", "output.save_solution=true")
    same = run_scene("cases/square_slip_separation.toml", "mesh.nx=8", f"reference.folder='{ref.folder}'")
    assert same.results["steps"]["h1_error"][0] <= 1e-12 * same.results["reference"]["h1_norm"]
    # A constant shift s of the x-displacement: L2 and H1 errors are |s| |Omega|^(1/2) = |s|.
    shift = 1e-4
    out = tmp_path / "shifted"
    proc = run_freefem("contact_foundation_2d.edp", "-nx", 8, "-reference", ref.folder,
                       "-error_shift_x", shift, "-outdir", out, "-vtu", 0)
    assert proc.returncode == 0, proc.stdout[-2000:]
    steps = json.loads((out / "results.json").read_text())["steps"]
    assert steps["l2_error"][0] == pytest.approx(shift, rel=1e-6)
    assert steps["h1_error"][0] == pytest.approx(shift, rel=1e-6)
