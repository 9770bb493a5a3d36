"""The body-fitted two-body solver and the fictitious-domain cross-check on coarse meshes."""

import json

import pytest

from conftest import run_cli, run_freefem
from lab.studies.fd2d import fitted_meshes

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)


def freefem(script, *args):
    proc = run_freefem(script, *args)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-2000:]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    out = tmp_path_factory.mktemp("fitted") / "run"
    disk, slab = fitted_meshes(out.parent, 0.025)
    freefem("tools/fitted_two_body_2d.edp", "-h", "0.025", "-mesh1", str(disk), "-mesh2", str(slab),
            "-save", "1", "-outdir", str(out))
    return out


def test_direct_run_meshes_the_bodies_without_gmsh(tmp_path):
    out = tmp_path / "run"
    freefem("tools/fitted_two_body_2d.edp", "-h", "0.05", "-outdir", str(out))
    r = json.loads((out / "results.json").read_text())
    assert r["status"] == "converged" and r["mesh_body1"] == "buildmesh"
    assert r["contact"]["force_balance_error"] < 1e-6


def test_fitted_solver_balances_the_disk(fitted):
    r = json.loads((fitted / "results.json").read_text())
    assert r["status"] == "converged"
    assert r["contact"]["force_balance_error"] < 1e-6
    assert -0.021 < r["probes"]["centre"][1] < -0.017


def test_crosscheck_against_itself_and_a_fictitious_domain_run(fitted, tmp_path):
    freefem("tools/fd_vs_fitted_2d.edp", "-fitted", str(fitted), "-fd", str(fitted),
            "-out", str(tmp_path / "self.json"))
    same = json.loads((tmp_path / "self.json").read_text())
    assert max(same[k] for k in ("l2_body1", "l2_body2", "h1_body1", "h1_body2")) < 1e-12
    fd = tmp_path / "fd"
    proc = run_cli("run", "cases/disk_on_slab.toml", "--out", str(fd), "--set", "mesh.nx=40",
                   "--set", "output.save_solution=true", "--set", "output.vtu=false")
    assert proc.returncode == 0, proc.stderr
    freefem("tools/fd_vs_fitted_2d.edp", "-fitted", str(fitted), "-fd", str(fd),
            "-out", str(tmp_path / "diff.json"))
    diff = json.loads((tmp_path / "diff.json").read_text())
    # both are about 5 % accurate in H1 at h = 1/40: they must agree to that level
    assert diff["h1_body1"] < 0.1 and diff["h1_body2"] < 0.1
    assert diff["l2_body1"] < 0.02 and diff["l2_body2"] < 0.02
