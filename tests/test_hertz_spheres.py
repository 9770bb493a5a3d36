"""Hertz's sphere on sphere (cases/hertz_spheres.toml) on a coarser grading than shipped
(grade_h 0.02 instead of 0.01: 38,508 DOFs, about 25 s): the contact radius, the
recovered peak and profile, the active area, the recovered pressure's integral and the
load against Hertz's solution (lab/studies/hertz3d.py computes them as the study
does), the under-resolution warning, and the 3D defaults' failure on the same mesh."""

import pytest

from conftest import driver_run
from lab.studies import hertz3d

pytestmark = pytest.mark.freefem

SPHERES = "cases/hertz_spheres.toml"
COARSER = ("mesh.grade_h=0.02", "output.vtu=false", "output.estimators=false")


@pytest.fixture(scope="module")
def coarser(tmp_path_factory):
    run = driver_run(SPHERES, tmp_path_factory.mktemp("hertz"), *COARSER)
    return run, hertz3d.hertz_row(run.results, run.folder)


def test_the_contact_zone_matches_hertz(coarser):
    _, row = coarser
    # measured: radius +0.57 %, recovered peak +2.8 %, recovered L2 7.1 %, raw L2 13.6 %,
    # active area 1.028 of pi a^2
    assert abs(row["radius_error"]) < 0.012
    assert abs(row["peak_error"]) < 0.035
    assert row["recovered_l2"] < 0.08
    assert row["raw_l2"] < 0.15
    assert 0.98 < row["active_area_ratio"] < 1.04
    # the Newton start follows the graded mesh's size at the contact (measured: 5 steps)
    assert row["newton_iterations"] <= 6
    # the recovery does not make the pressure worse than the raw multiplier
    assert row["recovered_l2"] < 0.6 * row["raw_l2"]


def test_the_recovered_pressure_carries_the_contact_force(coarser):
    run, row = coarser
    # measured 0.9914: the recovered pressure's integral against the raw multiplier's
    assert 0.985 < row["recovered_integral_ratio"] <= 1.0
    assert row["recovered_outside"] == 0.0      # nothing past 1.1 a
    assert run.results["pressure_recovery"]["active_only"] == 1
    # the raw multiplier integrated against body 2's normal is the contact force on body 1
    points = run.contact_samples()
    force_z = (points.weight * points.pressure * points.normal_z).sum()
    assert force_z == pytest.approx(run.results["contact"]["force_on_body1"][2], rel=1e-9)


def test_the_load_is_the_curved_volume_s(coarser):
    run, row = coarser
    contact = run.results["contact"]
    # the curved ball's volume, its cells' volume rules checked and refined: 6.1e-9 above
    # the exact one (measured); the contact force 1.24e-7 below F, 1.3e-7 below the
    # applied load (the balance's error)
    assert abs(row["volume_error"]) < 2e-8
    assert abs(row["force_error"]) < 3e-7
    assert contact["force_on_body1"][2] == pytest.approx(-contact["applied_force_body1"][2], rel=5e-7)


def test_an_unresolved_zone_is_said(coarser):
    run, row = coarser
    # measured 1.2 elements of h_K per half-width, where P2's recovery needs 2
    contact = run.results["contact"]
    assert 1.0 < row["zone_elements"] < 1.4
    assert contact["zone_elements_needed"] == 2 and contact["zone_resolved"] is False
    assert "WARNING: the contact zone is not resolved: its half-width spans 1.2 elements" in run.summary


def test_the_3d_defaults_miss_hertz_on_the_same_mesh(tmp_path):
    run = driver_run(SPHERES, tmp_path / "defaults", *COARSER, "method.gamma0=0.005",
                     "method.stabilization='none'", "method.geometry='p1'")
    row = hertz3d.hertz_row(run.results, run.folder)
    # what the scene's settings buy: with the defaults (measured) the recovered pressure
    # is 27 % off Hertz, the active area 0.81 of pi a^2 and the faceted ball's load 5.6 %
    # short; the scene's settings: 7.1 %, 1.028 and 1.65e-5
    assert row["recovered_l2"] > 0.2 and row["active_area_ratio"] < 0.9 and row["force_error"] < -0.04, row
