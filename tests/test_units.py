"""The default Nitsche parameter is invariant to the unit of stress.

Every stress-like input of a scene (Lame coefficients or E, body forces,
tractions) multiplied by s = 2.1e11 (Pa instead of units of E) must give the same
displacement to 1e-8 relative and the same Newton iterations: gamma = gamma0 h_K /
muStar (two bodies) or gamma0 h_K / E (foundation) with gamma0 dimensionless, and
the mass regularization is relative to muStar.
"""

import pytest

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)

S = 2.1e11
FAST_2D = ["mesh.nx=20", "method.degree=1", "output.vtu=false", "output.estimators=false"]


def relative(a, b):
    return abs(a - b) / max(abs(b), 1e-300)


def assert_same_solution(unit, scaled):
    for key, value in unit.results["norms"].items():
        assert relative(scaled.results["norms"][key], value) < 1e-8, key
    uy_unit = unit.results["probes"]["centre"][-1]
    uy_scaled = scaled.results["probes"]["centre"][-1]
    assert relative(uy_scaled, uy_unit) < 1e-8
    assert scaled.results["newton"]["iterations"] == unit.results["newton"]["iterations"]


def test_disk_on_slab_in_pascal(run_scene):
    unit = run_scene("cases/disk_on_slab.toml", *FAST_2D)
    scaled = run_scene("cases/disk_on_slab.toml", *FAST_2D,
                       f"body1.lambda={S}", f"body1.mu={S}", f"body2.lambda={S}", f"body2.mu={S}",
                       f"body1.body_force=[0.0, {-0.1 * S}]")
    assert_same_solution(unit, scaled)
    assert unit.results["gamma0_effective"] == 0.005        # muStar = 1: the Lame 1, 1 scenes are unchanged
    assert scaled.results["gamma0_effective"] == pytest.approx(0.005 / S, rel=1e-14)
    assert unit.results["gamma0"] == scaled.results["gamma0"] == 0.005     # as the scene gives it
    assert scaled.results["balance"]["balance_error"] < 1e-6


def test_ball_on_slab_in_pascal(run_scene):
    fast = ["mesh.nx=6", "output.vtu=false", "output.csv=false", "output.estimators=false"]
    unit = run_scene("cases/ball_on_slab.toml", *fast)
    scaled = run_scene("cases/ball_on_slab.toml", *fast,
                       f"body1.lambda={S}", f"body1.mu={S}", f"body2.lambda={S}", f"body2.mu={S}",
                       f"body1.body_force=[0.0, 0.0, {-0.1 * S}]")
    assert_same_solution(unit, scaled)


def test_square_on_foundation_in_pascal(run_scene):
    fast = ["mesh.nx=8", "method.degree=1", "output.vtu=false"]
    unit = run_scene("cases/square_slip_separation.toml", *fast, "material.E=1.0",
                     "loads.body_force=[0.0, -0.01]", "boundary.1.value=[0.0, 0.005]")
    scaled = run_scene("cases/square_slip_separation.toml", *fast, f"material.E={S}",
                       f"loads.body_force=[0.0, {-0.01 * S}]", f"boundary.1.value=[0.0, {0.005 * S}]")
    for key, value in unit.results["norms"].items():
        assert relative(scaled.results["norms"][key], value) < 1e-8, key
    force_unit = unit.results["contact"]["force_on_body"][1]
    assert relative(scaled.results["contact"]["force_on_body"][1] / S, force_unit) < 1e-8
    assert relative(scaled.results["contact"]["active_measure"], unit.results["contact"]["active_measure"]) < 1e-8
    assert scaled.results["newton"]["iterations"] == unit.results["newton"]["iterations"]
    assert unit.results["gamma0_effective"] == 1.0
    assert scaled.results["gamma0_effective"] == pytest.approx(1.0 / S, rel=1e-14)
