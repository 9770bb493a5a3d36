"""Scenes posed in the scene file (3D): the shipped shape-tree scenes."""

import json
import math
import subprocess

import numpy as np
import pytest

from tests.conftest import REPO, run_cli

QUIET = ("output.vtu=false", "output.estimators=false", "output.csv=false")


@pytest.mark.freefem
def test_rounded_cube_volume_and_balance(run_scene):
    """The exact volume of a box with rounded edges (Steiner's formula) reaches
    results.json; the curved cells of this coarse mesh (h = 0.077, about the edge radius)
    integrate it within 9.5e-10 (measured; the P1 polyhedron: 6.3 % below); the contact
    carries the weight."""
    run = run_scene("cases/rounded_cube_on_slab.toml", *QUIET)
    r = run.results
    inner, rad = 0.4 - 2 * 0.08, 0.08
    exact = inner ** 3 + 6 * inner ** 2 * rad + 3 * math.pi * inner * rad ** 2 + 4 / 3 * math.pi * rad ** 3
    assert r["measures"]["body1_exact"] == pytest.approx(exact, rel=1e-12)
    assert r["measures"]["body1"] == pytest.approx(exact, rel=5e-9)
    assert r["balance"]["balance_error"] < 1e-6 and not r["balance"]["unbalanced"]
    assert r["contact"]["force_on_body1"][2] == pytest.approx(0.1 * r["measures"]["body1"], rel=1e-6)


@pytest.mark.freefem
def test_sphere_on_sphere_balances_without_pins(run_scene, tmp_path):
    """A ball on a ball without pins: the mass term holds the rigid motions and carries
    under 1e-6 of the load (the gate); with pins they would carry 0.25 %."""
    r = run_scene("cases/sphere_on_sphere.toml", *QUIET).results
    assert r["supports"]["pins"] == 0 and not r["balance"]["unbalanced"]
    assert r["balance"]["balance_error"] < 1e-6
    assert r["probes"]["centre"][2] < 0
    assert r["measures"]["body1_exact"] is None      # the ball touches the box top: clipped, no formula
    pinned = run_cli("run", "cases/sphere_on_sphere.toml", "--set",
                     "rigid.fix_xy_points=[0.0, 0.0, 0.25, 0.0, 0.0, 0.35]", "--set", "rigid.fix_y_point=[0.1, 0.0, 0.25]",
                     "--set", "output.vtu=false", "--out", str(tmp_path / "pinned"))
    assert pinned.returncode == 3 and "pins carry" in pinned.stderr


def test_default_3d_scene_module_is_the_generated_one():
    proc = run_cli("scene-module", "cases/ball_on_slab.toml")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == (REPO / "freefem/lib/fd3d/scene_default.idp").read_text()


@pytest.mark.freefem
def test_reactions_per_support_add_up_to_each_body(run_scene):
    """results.json reactions.by_support in 3D: the slab held on the box bottom (z only),
    on the box side xmin (every component) and by Nitsche on a region of its top; the
    supports add up to the slab's reaction, which balances the ball's weight."""
    holds = ('body2.hold=[{ face = "zmin", components = "z" }, { face = "xmin" }, '
             '{ region = { type = "box", min = [0.3, -0.6, -0.35], max = [0.6, 0.6, -0.15] } }]')
    r = run_scene("cases/ball_on_slab.toml", *QUIET, "mesh.nx=8", holds).results
    by = r["reactions"]["by_support"]
    assert set(by) == {"body2 face zmin", "body2 face xmin", "body2 region 1"}
    body2 = np.sum(list(by.values()), axis=0)
    assert body2 == pytest.approx(r["reactions"]["body2"], rel=1e-9, abs=1e-14)
    assert all(abs(by[k][2]) > 1e-3 * abs(body2[2]) for k in by)
    weight = r["contact"]["force_on_body1"][2]
    assert body2[2] == pytest.approx(weight, rel=1e-6)


@pytest.mark.freefem
def test_held_body_touching_nothing_carries_its_load_by_its_hold(run_scene):
    """The ball 0.05 above the slab, held by Nitsche on its top cap: nothing touches, the
    cap's hold carries the ball's weight and the run passes the balance gate."""
    r = run_scene("cases/ball_on_slab.toml", *QUIET, "mesh.nx=8", "body1.centre=[0.0, 0.0, 0.05]",
                  "body1.hold=[{ region = { type = \"half_space\", point = [0.0, 0.0, 0.2], normal = [0.0, 0.0, -1.0] } }]",
                  "rigid.fix_xy_points=[]").results
    assert r["contact"]["force_on_body1"] == [0, 0, 0]
    assert r["balance"]["balance_error"] < 1e-12 and r["contact"]["force_balance_error"] < 1e-12
    assert r["reactions"]["body1"][2] == pytest.approx(0.1 * r["measures"]["body1"], rel=1e-8)


@pytest.mark.freefem
def test_error_tools_work_on_shape_tree_scenes(run_scene, tmp_path):
    """The error tools read a saved run's own level sets, so they measure any scene: a
    run against itself with its x-displacement shifted by c has L2 error |c| |body|^(1/2)
    on each body (2D: the ring, fd_error_2d.edp; 3D: the rounded cube, fd_error_3d.edp)."""
    shift = 1e-3
    for script, case, overrides, key in (
            ("fd_error_2d", "cases/ring_on_slab.toml", ["mesh.nx=40", "output.pressure_csv=false"], "reference_areas"),
            ("fd_error_3d", "cases/rounded_cube_on_slab.toml", ["mesh.nx=6", "method.degree=2", "output.csv=false"],
             None)):
        run = run_scene(case, "output.vtu=false", "output.estimators=false", "output.save_solution=true", *overrides)
        out = tmp_path / f"{script}.json"
        proc = subprocess.run(["FreeFem++", "-nw", "-v", "0", f"freefem/tools/{script}.edp", "-ref", str(run.folder),
                               "-run", str(run.folder), "-out", str(out), "-shift_x", repr(shift)],
                              cwd=REPO, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        errors = json.loads(out.read_text())
        for body in ("body1", "body2"):
            if key:
                measure, l2 = errors[key][body], errors["absolute"][f"l2_{body}"]
            else:
                measure, l2 = errors[body]["volume_ref"], errors[body]["l2_abs"]
            assert l2 == pytest.approx(shift * math.sqrt(measure), rel=1e-9), (script, body)


def test_exact_volume_of_a_cylinder_lying_in_the_box():
    """A cylinder whose length plus radius would reach the box but whose real extent does
    not keeps its exact volume (the bounds follow the axis: |a_i| L/2 + r sqrt(1 - a_i^2))."""
    from driver.geometry import placed_measure, read_shape

    box = [(-0.5, 0.5)] * 3
    lying = read_shape({"type": "cylinder", "centre": [0.0, 0.0, 0.0], "axis": [1.0, 0.0, 0.0], "radius": 0.2,
                        "length": 0.6}, 3, "body1.shape")
    assert placed_measure(lying, box) == pytest.approx(math.pi * 0.2 ** 2 * 0.6, rel=1e-14)
    tilted = read_shape({"type": "cylinder", "centre": [0.0, 0.0, 0.0], "axis": [1.0, 1.0, 0.0], "radius": 0.2,
                         "length": 1.2}, 3, "body1.shape")
    assert placed_measure(tilted, box) is None      # its ends leave the box: clipped
