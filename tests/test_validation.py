"""Bad input gives one clear message naming the key and the file, and a non-zero exit."""


import pytest

from conftest import REPO, run_cli, run_freefem

SCENE = "cases/square_slip_separation.toml"


def run_with(*overrides, scene=SCENE, tmp_path=None):
    args = ["run", scene]
    for item in overrides:
        args += ["--set", item]
    if tmp_path is not None:
        args += ["--out", str(tmp_path / "run")]
    return run_cli(*args)


@pytest.mark.parametrize("override, key, words", [
    ("method.gamma0=0.0", "method.gamma0", "must be > 0"),
    ("method.gamma0=-1e-6", "method.gamma0", "must be > 0"),
    ("method.degree=3", "method.degree", "must be one of 1, 2"),
    ("mesh.nx=0", "mesh.nx", "must be > 0"),
    ("mesh.nx=-8", "mesh.nx", "must be > 0"),
    ("material.nu=0.5", "material.nu", "must lie in (-1, 0.5)"),
    ("material.nu=-1.0", "material.nu", "must lie in (-1, 0.5)"),
    ("mesh.nx=16.5", "mesh.nx", "expected an integer"),
    ("method.theta='minus one'", "method.theta", "expected a number"),
    ("loads.body_force=[1.0]", "loads.body_force", "expected 2 numbers"),
    ("method.tehta=1.0", "method.tehta", "unknown key"),
    ("solver.newton_max=0", "solver.newton_max", "must be >= 1"),
    ("boundary.0.label='west'", "boundary.0.label", "a box has the sides"),
    ("boundary.0.type='glue'", "boundary.0.type", "must be one of"),
    ("scene.script='nonexistent'", "scene.script", "unknown script"),
])
def test_each_rule_names_key_and_file(override, key, words):
    proc = run_with(override)
    assert proc.returncode == 2
    message = proc.stderr.strip()
    assert message.count("\n") == 0, "one line, no traceback"
    assert "Traceback" not in proc.stderr
    assert f"'{key}'" in message and SCENE in message and words in message


def test_malformed_toml(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[scene]\nname = 'x\nscript = 3\n")
    proc = run_cli("run", str(bad))
    assert proc.returncode == 2
    assert "malformed TOML" in proc.stderr and str(bad) in proc.stderr
    assert "Traceback" not in proc.stderr


def test_missing_scene_file():
    proc = run_cli("run", "cases/no_such_scene.toml")
    assert proc.returncode == 2 and "cannot read scene file" in proc.stderr


def test_both_material_forms_rejected():
    proc = run_with("material.lambda=1.0", "material.mu=1.0")
    assert proc.returncode == 2 and "'material'" in proc.stderr and "not both" in proc.stderr


@pytest.mark.freefem
def test_freefem_script_error_is_reported(tmp_path):
    broken = tmp_path / "broken.edp"
    source = (REPO / "freefem" / "contact_foundation_2d.edp").read_text()
    # A real script error: an undefined name, the kind a user's edit introduces.
    # Its includes name their files from the repository root, where the driver runs FreeFEM.
    broken.write_text(source + "\nreal brokenValue = vBulkTypo + 1;\n")
    out = tmp_path / "run"
    proc = run_cli("run", SCENE, "--script", str(broken), "--out", str(out))
    assert proc.returncode == 4
    assert "square_slip_separation" in proc.stderr and "FreeFEM failed" in proc.stderr
    assert "vBulkTypo" in proc.stderr           # FreeFEM's own message is shown
    assert not (out / "results.json").exists()
    assert not out.exists() and (tmp_path / "run.failed" / "freefem.log").is_file()


@pytest.mark.freefem
def test_newton_failure_is_reported(tmp_path):
    proc = run_with("solver.newton_max=2", tmp_path=tmp_path)
    assert proc.returncode == 3
    assert "square_slip_separation" in proc.stderr and "did not converge in 2 iterations" in proc.stderr
    failed = tmp_path / "run.failed"
    assert not (tmp_path / "run").exists()
    assert not (failed / "results.json").exists() and (failed / "failure.json").is_file()


@pytest.mark.freefem
def test_freefem_direct_input_check():
    # The scripts check their own parameters when run directly, without the driver.
    proc = run_freefem("contact_foundation_2d.edp", "-gamma0", -1, "-outdir", "runs/test-direct")
    assert proc.returncode == 2 and "option -gamma0: -1 must be > 0" in proc.stdout + proc.stderr
