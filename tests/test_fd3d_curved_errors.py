"""fd_error_3d.edp against a reference solved on the curved cut geometry (-geometry curved
-save 1): it integrates on the reference's saved curved cut cells, not on the P1 cut.

Ball on slab, P2, theta = -1; about 30 s on two cores.
"""

import json
import math

import pytest

from tests.conftest import run_freefem, tool_errors

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)

SHIFT = (1e-3, 0.0, -2e-3)


def solve(folder, nx, geometry="curved"):
    proc = run_freefem("fd_contact_3d.edp", "-Ddegree=2", "-nx", nx, "-geometry", geometry, "-save", 1,
                       "-estimators", 0, "-vtu", 0, "-csv", 0, "-outdir", folder)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return json.loads((folder / "results.json").read_text())


def errors(ref, run, out, *extra):
    return tool_errors("fd_error_3d.edp", ref, run, *extra, out=out)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("curved3d")
    return base, {nx: solve(base / f"nx{nx}", nx) for nx in (4, 8)}


def test_curved_reference_saves_its_cut_quadrature(runs):
    base, _ = runs
    meta = (base / "nx8" / "solution_meta.txt").read_text()
    assert "curved 1" in meta
    assert (base / "nx8" / "cut_quadrature_body1.txt").is_file()


@pytest.mark.parametrize("path", ["nested", "direct"])
def test_shift_against_itself_on_the_curved_cells(runs, path):
    # A constant shift s of the reference against itself: L2 error |s| sqrt(|body|), no
    # gradient error, on both error paths (nested nodes; -direct 1: points of the graded case).
    base, results = runs
    extra = ["-shift_x", SHIFT[0], "-shift_y", SHIFT[1], "-shift_z", SHIFT[2]] + (["-direct", 1] if path == "direct" else [])
    e = errors(base / "nx8", base / "nx8", base / f"self_{path}.json", *extra)
    shift = math.sqrt(sum(s * s for s in SHIFT))
    r = results[8]
    for b in (1, 2):
        body = e[f"body{b}"]
        assert body["l2_abs"] == pytest.approx(shift * math.sqrt(body["volume_ref"]), rel=1e-10)   # measured 4e-14
        assert body["h1_abs"] == pytest.approx(body["l2_abs"], rel=1e-10)
        # the reference norms are the solver's own on its curved geometry
        assert body["l2_ref"] == pytest.approx(r["norms"][f"l2_body{b}"], rel=1e-9)
        assert body["h1_ref"] == pytest.approx(r["norms"][f"h1_body{b}"], rel=1e-9)
    # the curved ball: volume error -1.8e-4 (the P1 cut at nx = 8: -0.127)
    exact = r["measures"]["body1_exact"]
    assert abs(e["body1"]["volume_ref"] - exact) / exact < 3e-4
    assert e["body1"]["curved_points"] > 0


def test_point_path_agrees_with_the_nested_one(runs):
    # nx = 4 against nx = 8 (nested meshes): the quadrature-point path (-direct 1) reads the
    # coarse field at the curved points, the nested one interpolates it exactly on the
    # reference nodes. Measured: H1 0.316542 / 0.49155 on both (6 digits).
    base, _ = runs
    nested = errors(base / "nx8", base / "nx4", base / "e_nested.json")
    direct = errors(base / "nx8", base / "nx4", base / "e_direct.json", "-direct", 1)
    assert nested["nested"] == 1 and direct["nested"] == 0
    for b in (1, 2):
        for norm in ("l2_rel", "h1_rel"):
            assert direct[f"body{b}"][norm] == pytest.approx(nested[f"body{b}"][norm], rel=1e-4)
    assert 0.2 < nested["body1"]["h1_rel"] < 0.5
