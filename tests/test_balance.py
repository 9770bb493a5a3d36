"""No silent wrong answers: the gates after every solve (freefem/lib/core/gates.idp:
a floating body touching nothing, penetration and drift against the bodies' sizes, load
carried by the rigid-motion regularization), failed linear solves, a body the mesh
cannot see. Small P1 runs of the disk on slab and of the ball on slab (a second or two
each)."""

import json

import pytest

from conftest import run_cli, run_freefem

FAST = ["--set", "mesh.nx=20", "--set", "method.degree=1", "--set", "output.vtu=false",
        "--set", "output.estimators=false"]
FAST_3D = ["--set", "mesh.nx=10", "--set", "output.vtu=false", "--set", "output.estimators=false",
           "--set", "output.csv=false"]
SIDEWAYS = ["--set", "body1.body_force=[0.3, -1.0]"]


def lame(young, nu=0.3):
    """body1.lambda and body1.mu overrides of Young's modulus `young` (E and nu are not
    overridable on scenes that give lambda and mu)."""
    mu, lam = young / (2 * (1 + nu)), young * nu / ((1 + nu) * (1 - 2 * nu))
    return ["--set", f"body1.lambda={lam!r}", "--set", f"body1.mu={mu!r}"]


def driver(tmp_path, *extra):
    return run_cli("run", "cases/disk_on_slab.toml", *FAST, *extra, "--out", str(tmp_path / "run"))


def driver_3d(tmp_path, *extra):
    return run_cli("run", "cases/ball_on_slab.toml", *FAST_3D, *extra, "--out", str(tmp_path / "run"))


def results(tmp_path):
    return json.loads((tmp_path / "run" / "results.json").read_text())


def failure(tmp_path):
    assert not (tmp_path / "run.failed" / "results.json").exists()
    return json.loads((tmp_path / "run.failed" / "failure.json").read_text())


def one_error_line(proc):
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, proc.stderr
    return lines[0]



@pytest.mark.freefem
def test_the_balance_measures_the_load_the_contact_does_not_carry(tmp_path):
    """mass_eps = 1e-3 (kept by allow_unbalanced): the mass term carries part of the disk's
    weight, which acts along y, the last axis; the contact's force balance must report
    that part (the mass share) and not only the x components."""
    proc = driver(tmp_path, "--set", "rigid.mass_eps=1e-3", "--set", "solver.allow_unbalanced=true")
    assert proc.returncode == 0, proc.stderr
    r = results(tmp_path)
    share = r["balance"]["mass_share"]
    assert share > 1e-5
    # measured: 1.6456113e-4 against a mass share of 1.6456227e-4 (6.9e-6 apart)
    assert r["contact"]["force_balance_error"] == pytest.approx(share, rel=1e-4)

@pytest.mark.freefem
def test_shipped_scene_is_carried_by_the_contact(tmp_path):
    proc = driver(tmp_path)
    assert proc.returncode == 0, proc.stderr
    balance = results(tmp_path)["balance"]
    # measured: pins 6.1e-11, mass term 1.6e-8 of the disk's weight, round-off 2.9e-13
    assert balance["pins_share"] < 1e-9 and balance["mass_share"] < 1e-7
    assert balance["balance_error"] < 1e-7 and balance["unbalanced"] == 0
    assert balance["roundoff_share"] < 1e-11 and balance["sideways_share"] == 0


@pytest.mark.freefem
def test_shipped_scenes_pass_the_plausibility_gates(tmp_path):
    # measured, disk (P1 NX = 20): penetration 4.5e-4 of the slab's size 0.25, the disk's
    # drift 0.033 of its size 0.5; ball (nx = 10): 4.6e-3 and 0.046
    assert driver(tmp_path).returncode == 0
    plaus = results(tmp_path)["plausibility"]
    assert abs(plaus["size_body1"] - 0.5) < 1e-9 and abs(plaus["size_body2"] - 0.25) < 1e-9
    assert 3e-4 < plaus["penetration_ratio"] < 6e-4 and 0.03 < plaus["drift_ratio_body1"] < 0.036
    assert plaus["implausible"] == 0
    three = tmp_path / "3d"
    assert driver_3d(three).returncode == 0
    plaus = results(three)["plausibility"]
    assert 4e-3 < plaus["penetration_ratio"] < 5.2e-3 and 0.042 < plaus["drift_ratio_body1"] < 0.051
    balance = results(three)["balance"]
    assert balance["pins_share"] < 1e-9 and balance["balance_error"] < 5e-8    # 1.9e-10, 3.0e-8


@pytest.mark.freefem
def test_soft_body_overlapping_the_slab_is_refused(tmp_path):
    # E = 1e-6 under the default weight: Newton converges, the disk overlaps the slab by
    # 32.8 (131 times the slab's size 0.25) and drifts by 5172 times its own size
    proc = driver(tmp_path, *lame(1e-6))
    assert proc.returncode == 3
    line = one_error_line(proc)
    assert "the bodies overlap by up to 32.75" in line and "131.0" in line and "smaller body's size 0.25" in line
    assert "floating body 1 drifts by" in line
    fail = failure(tmp_path)
    assert fail["status"] == "implausible" and 30 < fail["max_penetration"] < 35


@pytest.mark.freefem
def test_soft_ball_overlapping_the_slab_is_refused_in_3d(tmp_path):
    proc = driver_3d(tmp_path, *lame(1e-6))
    assert proc.returncode == 3
    assert "the bodies overlap by up to" in one_error_line(proc)
    fail = failure(tmp_path)
    assert fail["status"] == "implausible" and fail["max_penetration"] > 10 * 0.25


@pytest.mark.freefem
def test_implausible_run_kept_when_allowed_is_flagged(tmp_path):
    proc = driver(tmp_path, *lame(1e-6), "--set", "solver.allow_implausible=true")
    assert proc.returncode == 0, proc.stderr
    assert "IMPLAUSIBLE (kept by solver.allow_implausible): the bodies overlap" in proc.stdout
    plaus = results(tmp_path)["plausibility"]
    assert plaus["implausible"] == 1 and plaus["allow_implausible"] == 1 and plaus["penetration_ratio"] > 100


@pytest.mark.freefem
def test_ball_held_sideways_by_the_mass_term_alone_is_refused_as_drifting(tmp_path):
    # no pins, a sideways load of 5.7e-6 of the weight, mass_eps = 1e-9 and the balance
    # gate waived: the ball's centre drifted by (351, 453) with exit 0; now 1146 times its size
    proc = driver_3d(tmp_path, "--set", "mesh.nx=8", "--set", "rigid.fix_xy_points=[]",
                     "--set", "body1.body_force=[3.51e-7, 4.53e-7, -0.1]", "--set", "rigid.mass_eps=1e-9",
                     "--set", "solver.allow_unbalanced=true")
    assert proc.returncode == 3
    line = one_error_line(proc)
    assert "floating body 1 drifts by 573." in line and "1146." in line
    assert "only the mass regularization holds it against a load component along the contact" in line
    fail = failure(tmp_path)
    assert fail["status"] == "implausible" and 570 < fail["drift_body1"] < 576


@pytest.mark.freefem
def test_stiff_ball_within_the_round_off_passes(tmp_path):
    # E1 = 1e6 on the slab's E = 2.5, load purely vertical: the pins carry 2.3e-6 of the
    # load, the round-off of the solve is 1.3e-4 of it (gamma, set by the soft slab, makes
    # the ball's Nitsche terms thousands of times its stiffness). Refused before as "a load
    # component along the contact (sideways)".
    proc = driver_3d(tmp_path, *lame(1e6))
    assert proc.returncode == 0, proc.stderr
    assert "sideways" not in proc.stdout + proc.stderr
    balance = results(tmp_path)["balance"]
    assert 1.8e-6 < balance["pins_share"] < 3e-6 and 1.1e-4 < balance["roundoff_share"] < 1.6e-4
    assert balance["sideways_share"] == 0 and balance["unbalanced"] == 0


@pytest.mark.freefem
def test_stiffer_ball_is_refused_for_its_round_off(tmp_path):
    # E1 = 1e7: round-off 1.3e-2 of the load, beyond the 1 % the gate accepts
    proc = driver_3d(tmp_path, *lame(1e7))
    assert proc.returncode == 3
    line = one_error_line(proc)
    assert "the round-off of the solve reaches 0.013" in line and "sideways" not in line
    fail = failure(tmp_path)
    assert fail["status"] == "unbalanced" and 1.1e-2 < fail["roundoff_share"] < 1.6e-2


@pytest.mark.freefem
def test_sideways_load_on_the_mass_term_names_the_missing_pins(tmp_path):
    # no pins, mass_eps = 1e-3: the mass term carries 2.6e-4 of the load, which has a
    # sideways share of 2e-4; the advice is pins or a support, not a smaller mass_eps
    proc = driver(tmp_path, "--set", "rigid.fix_x_points=[]", "--set", "rigid.mass_eps=1e-3",
                  "--set", "body1.body_force=[2e-5, -0.1]")
    assert proc.returncode == 3
    line = one_error_line(proc)
    assert "the mass regularization (mass_eps) carries 0.0259" in line and "sideways share 0.0002 " in line
    assert "pins or a support must" in line and "lower mass_eps" not in line


@pytest.mark.freefem
def test_ball_pulled_away_is_a_floating_body_in_3d(tmp_path):
    # before: "semi-smooth Newton did not converge in 30 iterations"
    proc = driver_3d(tmp_path, "--set", "mesh.nx=8", "--set", "body1.body_force=[0, 0, 0.1]")
    assert proc.returncode == 3
    assert "body 1 does not touch body 2 (no active contact point)" in one_error_line(proc)
    assert failure(tmp_path)["status"] == "floating_body"


def test_body_smaller_than_the_mesh_is_named_with_the_mesh_size(tmp_path):
    small = ["--set", "body1.radius=0.01", "--set", "body1.centre=[0, 0, -0.24]",
             "--set", "rigid.fix_xy_points=[]"]
    proc = run_cli("scene-module", "cases/ball_on_slab.toml", "--set", "mesh.nx=8", *small)
    assert proc.returncode == 2
    assert "spans 0.02 inside the box, less than the mesh size h = 0.125" in proc.stderr
    assert "misses the box" not in proc.stderr
    # between the driver's samples (step 1/60) but not below the mesh size: accepted
    assert run_cli("scene-module", "cases/ball_on_slab.toml", "--set", "mesh.nx=64", *small).returncode == 0
    far = run_cli("scene-module", "cases/ball_on_slab.toml", *small[:2], "--set", "body1.centre=[0, 0, 0.8]",
                  "--set", "rigid.fix_xy_points=[]")
    assert far.returncode == 2 and "misses the box" in far.stderr


@pytest.mark.freefem
def test_sideways_load_on_the_pins_is_refused(tmp_path):
    proc = driver(tmp_path, *SIDEWAYS)
    assert proc.returncode == 3
    assert "pins carry 28.7" in proc.stderr and "(sideways share 0.2873" in one_error_line(proc)
    failure = json.loads((tmp_path / "run.failed" / "failure.json").read_text())
    assert failure["status"] == "unbalanced" and failure["pins_share"] > 0.28
    assert not (tmp_path / "run.failed" / "results.json").exists()


@pytest.mark.freefem
def test_sideways_load_kept_when_allowed_is_flagged(tmp_path):
    proc = driver(tmp_path, *SIDEWAYS, "--set", "solver.allow_unbalanced=true")
    assert proc.returncode == 0, proc.stderr
    assert "UNBALANCED (kept by solver.allow_unbalanced)" in proc.stdout
    balance = json.loads((tmp_path / "run" / "results.json").read_text())["balance"]
    assert balance["unbalanced"] == 1 and balance["pins_share"] > 0.28


@pytest.mark.freefem
def test_singular_stiffness_is_named(tmp_path):
    # E1/E2 = 1e30: no digit left in double precision, not "does not touch"
    proc = driver(tmp_path, "--set", "body1.lambda=1e30", "--set", "body1.mu=1e30")
    assert proc.returncode == 3
    assert "singular or non-finite linear system" in proc.stderr and "does not touch" not in proc.stderr
    failure = json.loads((tmp_path / "run.failed" / "failure.json").read_text())
    assert failure["status"] == "singular_system"


@pytest.mark.freefem
def test_direct_runs_with_extreme_parameters_fail_with_exit_3(tmp_path):
    out = tmp_path / "direct"
    proc = run_freefem("fd_contact_2d.edp", "-Ddegree=1", "-nx", 20, "-estimators", 0, "-vtu", 0,
                       "-gamma0", "1e300", "-outdir", out)
    assert proc.returncode == 3
    failure = json.loads((out / "failure.json").read_text())
    assert failure["status"] == "singular_system" and "singular" in failure["message"]
    assert not (out / "results.json").exists()
