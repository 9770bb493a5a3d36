"""One answer per input: identical runs give identical numbers, adaptation included.

MUMPS orders systems above a few thousand unknowns with Scotch, whose threaded
ordering varied from run to run; the solutions then differed in the last digits and
the estimator-driven adaptmesh turned that into different meshes.
freefem/lib/core/sparse_solver.idp keeps Scotch on one thread."""

import math
import re

import pytest

from conftest import REPO

DISK = "cases/disk_on_slab.toml"

# Measurements of the run, not of the input: CPU seconds per phase and per adaptive
# step, the driver's wall time and peak memory; and where and when it ran (provenance:
# its date, its folder in the command).
EXCLUDED_PATHS = {
    ("timings_cpu_s",),
    ("steps", "cpu_s"),
    ("adapt", "estimate_cpu_s"),
    ("adapt", "remesh_cpu_s"),
    ("wall_s",),
    ("peak_rss_mb",),
    ("provenance",),
}


def differences(a, b, path=()):
    """Paths (tuples of keys and indices) where two JSON values differ, excluded paths skipped."""
    if path in EXCLUDED_PATHS:
        return []
    if isinstance(a, dict) and isinstance(b, dict):
        found = [path + (key,) for key in sorted(set(a) ^ set(b))]
        for key in sorted(set(a) & set(b)):
            found += differences(a[key], b[key], path + (key,))
        return found
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [path]
        found = []
        for i, (x, y) in enumerate(zip(a, b)):
            found += differences(x, y, path + (i,))
        return found
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return []
    return [] if (type(a) is type(b) and a == b) else [path]


@pytest.mark.freefem
def test_adaptive_runs_are_identical(run_scene):
    # P2 on NX = 20 with two adaptmesh steps: 1,652 then about 5,000 and 9,000 DOFs,
    # so the adapted steps are ordered by Scotch (AMF below a few thousand).
    overrides = ("mesh.nx=20", "adapt.steps=2", "output.vtu=false")
    first, second = run_scene(DISK, *overrides), run_scene(DISK, *overrides)
    assert len(first.results["steps"]["dofs"]) == 3
    assert first.results["steps"]["dofs"][-1] > 5000
    for key in EXCLUDED_PATHS:          # the exclusions name keys that exist
        value = first.results
        for part in key:
            value = value[part]
    diff = differences(first.results, second.results)
    assert diff == [], f"results.json differs between identical runs at {diff[:10]}"
    pressure = "contact_pressure.csv"
    assert (first.folder / pressure).read_bytes() == (second.folder / pressure).read_bytes()


def test_contact_scripts_load_mumps_through_sparse_solver():
    # Loading MUMPS_seq anywhere else would bring the threaded Scotch ordering back.
    direct = re.compile(r'^\s*load\s+"MUMPS_seq"', re.MULTILINE)
    sparse = re.compile(r'^\s*(?:IFMACRO\(!\w+\)\s*)?include\s+"freefem/lib/core/sparse_solver\.idp"', re.MULTILINE)
    solver = REPO / "freefem" / "lib" / "core" / "sparse_solver.idp"
    for path in sorted((REPO / "freefem").rglob("*.[ei]dp")):
        if path.resolve() != solver.resolve():
            assert not direct.search(path.read_text()), f"{path.name} loads MUMPS_seq directly"
    # The Newton solves use sparsesolver: every script that includes the Newton gets it.
    newton = REPO / "freefem" / "lib" / "core" / "newton.idp"
    assert sparse.search(newton.read_text()), "core/newton.idp does not include core/sparse_solver.idp"
