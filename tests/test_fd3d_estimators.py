"""3D residual estimators and tetgen refinement (ball on slab, P1, coarse meshes)."""

import math

import meshio
import numpy as np
import pytest

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)

BALL = "cases/ball_on_slab.toml"
BALL_VOLUME = 4.0 / 3.0 * math.pi * 0.25 ** 3


def test_estimators_finite_positive_and_consistent(run_scene):
    run = run_scene(BALL, "mesh.nx=6")
    est = run.results["estimator"]
    for key in ("eta", "eta1", "eta2", "eta3", "eta4", "eta_body1", "eta_body2"):
        assert math.isfinite(est[key]) and est[key] > 0, key
    # the slab is clamped strongly on the box bottom: no Nitsche-Dirichlet residual
    assert est["eta5"] == 0
    parts = est["eta1"] ** 2 + est["eta2"] ** 2 + est["eta3"] ** 2 + est["eta4"] ** 2 + est["eta5"] ** 2
    assert est["eta"] == pytest.approx(math.sqrt(parts), rel=1e-12)
    assert est["eta"] == pytest.approx(math.hypot(est["eta_body1"], est["eta_body2"]), rel=1e-10)
    # P1: div sigma = 0 on every element, and only the ball carries a load: eta1 is
    # exactly h_K |f| |K cap ball|^(1/2) summed, f constant (zeta = 0)
    assert est["zeta"] < 1e-12
    steps = run.results["steps"]
    assert len(steps["dofs"]) == 1 and steps["eta"][0] == est["eta"]
    # per-element fields on the background mesh
    vtu = meshio.read(run.folder / "estimators.vtu")
    eta_k = np.ravel(vtu.cell_data["eta"][0])
    eta1_k = np.ravel(vtu.cell_data["eta1"][0])
    assert len(eta_k) == run.results["elements"]
    assert np.sqrt((eta_k ** 2).sum()) == pytest.approx(est["eta"], rel=1e-5)
    # eta1 lives on elements meeting the ball only (z > -0.25 - h); the slab has no load
    cells = vtu.cells[0].data
    centroids = vtu.points[cells].mean(axis=1)
    assert np.all(eta1_k[np.linalg.norm(centroids, axis=1) > 0.25 + 0.3] == 0)


def test_estimators_can_be_switched_off(run_scene):
    run = run_scene(BALL, "mesh.nx=6", "output.estimators=false")
    assert "estimator" not in run.results
    assert run.results["newton"]["converged_by"] in ("tolerance", "roundoff_floor")


def test_adaptive_refinement_lowers_eta_and_keeps_the_ball(run_scene):
    run = run_scene(BALL, "mesh.nx=6", "adapt.steps=2", "output.csv=false")
    steps, r = run.results["steps"], run.results
    assert len(steps["dofs"]) == 3
    assert steps["dofs"][0] < steps["dofs"][1] < steps["dofs"][2]
    assert steps["eta"][2] < steps["eta"][1] < steps["eta"][0]
    # element growth per step near the requested 2 (bisected against tetgen's count)
    assert all(1.4 < g < 3.0 for g in steps["element_growth_after"][:2])
    # the curved cells keep the exact ball on every adapted mesh (7.7e-9, 4.2e-9, 2.5e-9 measured)
    for volume in steps["measure_body1"]:
        assert volume == pytest.approx(BALL_VOLUME, rel=2e-8)
    # every step's bodies for ParaView, timestep by timestep (bodies.pvd)
    pvd = (run.folder / "bodies.pvd").read_text()
    assert [pvd.count(f'timestep="{k}"') for k in range(4)] == [2, 2, 2, 0]
    assert all((run.folder / f"steps/body{b}_{k}.vtu").is_file() for b in (1, 2) for k in (0, 1))
    for volume in steps["measure_body2"]:
        assert volume == pytest.approx(0.25, rel=1e-8)
    # the clamp (label 5) and the pins survive remeshing: the equilibrium holds
    assert r["contact"]["force_balance_error"] < 0.01
    assert abs(r["probes"]["centre"][0]) < 1e-6 and abs(r["probes"]["centre"][1]) < 1e-6
    assert r["adapt"]["steps_done"] == 2
