"""No silent wrong answers: load carried by the rigid-motion regularization, failed
linear solves. Small P1 runs of the disk on slab (a second or less each)."""

import json

from conftest import run_cli, run_freefem

FAST = ["--set", "mesh.nx=20", "--set", "method.degree=1", "--set", "output.vtu=false",
        "--set", "output.estimators=false"]
SIDEWAYS = ["--set", "body1.body_force=[0.3, -1.0]"]


def driver(tmp_path, *extra):
    return run_cli("run", "cases/disk_on_slab.toml", *FAST, *extra, "--out", str(tmp_path / "run"))


def test_shipped_scene_is_carried_by_the_contact(tmp_path):
    proc = driver(tmp_path)
    assert proc.returncode == 0, proc.stderr
    balance = json.loads((tmp_path / "run" / "results.json").read_text())["balance"]
    # measured: pins 5e-11, mass term 1.7e-8 of the disk's weight
    assert balance["pins_share"] < 1e-9 and balance["mass_share"] < 1e-7
    assert balance["balance_error"] < 1e-7 and balance["unbalanced"] == 0


def test_sideways_load_on_the_pins_is_refused(tmp_path):
    proc = driver(tmp_path, *SIDEWAYS)
    assert proc.returncode == 3
    assert "pins carry 28.7" in proc.stderr and "sideways" in proc.stderr
    failure = json.loads((tmp_path / "run.failed" / "failure.json").read_text())
    assert failure["status"] == "unbalanced" and failure["pins_share"] > 0.28
    assert not (tmp_path / "run.failed" / "results.json").exists()


def test_sideways_load_kept_when_allowed_is_flagged(tmp_path):
    proc = driver(tmp_path, *SIDEWAYS, "--set", "solver.allow_unbalanced=true")
    assert proc.returncode == 0, proc.stderr
    assert "UNBALANCED (kept by solver.allow_unbalanced)" in proc.stdout
    balance = json.loads((tmp_path / "run" / "results.json").read_text())["balance"]
    assert balance["unbalanced"] == 1 and balance["pins_share"] > 0.28


def test_singular_stiffness_is_named(tmp_path):
    # E1/E2 = 1e30: no digit left in double precision, not "does not touch"
    proc = driver(tmp_path, "--set", "body1.lambda=1e30", "--set", "body1.mu=1e30")
    assert proc.returncode == 3
    assert "singular or non-finite linear system" in proc.stderr and "does not touch" not in proc.stderr
    failure = json.loads((tmp_path / "run.failed" / "failure.json").read_text())
    assert failure["status"] == "singular_system"


def test_direct_runs_with_extreme_parameters_fail_with_exit_3(tmp_path):
    out = tmp_path / "direct"
    proc = run_freefem("fd_contact_2d.edp", "-Ddegree=1", "-nx", 20, "-estimators", 0, "-vtu", 0,
                       "-gamma0", "1e300", "-outdir", out)
    assert proc.returncode == 3
    failure = json.loads((out / "failure.json").read_text())
    assert failure["status"] == "singular_system" and "singular" in failure["message"]
    assert not (out / "results.json").exists()
