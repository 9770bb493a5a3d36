"""Helpers: run the driver the way a user does and read what FreeFEM wrote."""

import json
import os
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pandas as pd
import pytest

REPO = Path(__file__).resolve().parent.parent

# A 2D scene: body 1 (any shape, formatted in) floating on the legacy slab {y < -0.25},
# pinned in x at (0, 0) and (0, -0.1), P1 on an nx x nx background mesh.
BODY_ON_SLAB = """
[scene]
name = "body_on_slab"
script = "fd_contact_2d"
[mesh]
nx = {nx}
[body1]
E = 1.0
nu = 0.3
body_force = [0.0, -0.1]
shape = {shape}
[body2]
shape = "slab"
top = -0.25
E = 1.0
nu = 0.3
[rigid]
fix_x_points = [0.0, 0.0, 0.0, -0.1]
[method]
degree = 1
"""


def run_cli(*args, cwd=REPO):
    """python -m driver ARGS from any working folder; returns the CompletedProcess (never raises)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "driver", *args], cwd=cwd,
                          capture_output=True, text=True, env=env)


def run_freefem(script, *args, env=None):
    """FreeFem++ -nw from the repository root (never raises) on a script of freefem/
    (its name there) or on a test's own script (a Path); env: the process environment
    (default this one's)."""
    target = str(script) if isinstance(script, Path) else f"freefem/{script}"
    return subprocess.run(["FreeFem++", "-nw", "-v", "0", target, *map(str, args)],
                          cwd=REPO, env=env, capture_output=True, text=True)


def saved_run(case, folder, *overrides):
    """python -m driver run CASE --out FOLDER with the solution saved (what the error
    tools read) and no VTU, overrides as 'key=value'; fails the test with the driver's
    message."""
    args = ["run", str(case), "--out", str(folder), "--set", "output.save_solution=true", "--set", "output.vtu=false"]
    for item in overrides:
        args += ["--set", item]
    proc = run_cli(*args)
    assert proc.returncode == 0, proc.stderr
    return folder


def tool_errors(tool, ref, run, *extra, out=None):
    """The errors.json that freefem/tools/TOOL (fd_error_2d.edp, fd_error_3d.edp) writes
    for RUN against REF (default path: RUN/errors.json), extra flags after them."""
    out = out or Path(run) / "errors.json"
    proc = run_freefem(f"tools/{tool}", "-ref", ref, "-run", run, "-out", out, *extra)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return json.loads(Path(out).read_text())


# Newton's stopping rule (core/newton.idp): the last step's active set is the one of
# the step before and its residual is below the tolerance, or (the round-off floor)
# the set stayed for two steps and the residual is below this factor times it.
ROUNDOFF_FLOOR_FACTOR = 1e3


def check_newton_stop(results, scene):
    """A converged run's last Newton step kept its active set and met the tolerance
    the scene asked for (scene: the run's scene.json, None for a direct run)."""
    newton = results.get("newton")
    if results.get("status") != "converged" or not newton or "changed_measure" not in newton:
        return
    tol = scene["solver"]["newton_tol"] if scene and "solver" in scene else newton.get("tolerance")
    contact = results.get("contact", {})
    boundary = max(contact.get("boundary_measure", 1.0), 1.0)
    changed, residual = newton["changed_measure"], newton["residual"]
    assert changed[-1] <= 1e-12 * boundary, f"Newton stopped on a changed active set: {changed}"
    floor = newton.get("converged_by") == "roundoff_floor"
    if floor:
        assert len(changed) > 1 and changed[-2] <= 1e-12 * boundary, f"round-off floor on a new active set: {changed}"
    if tol is not None:   # the foundation script's direct runs do not report it
        limit = ROUNDOFF_FLOOR_FACTOR * tol if floor else tol
        assert residual[-1] < limit, f"Newton stopped at residual {residual[-1]}, above {limit}"


class Run:
    """A converged run's folder: results.json read, and its Newton stop checked; summary:
    what the driver printed, when it ran it."""

    def __init__(self, folder, summary=""):
        self.folder = Path(folder)
        self.results = json.loads((self.folder / "results.json").read_text())
        self.summary = summary
        scene = self.folder / "scene.json"
        check_newton_stop(self.results, json.loads(scene.read_text()) if scene.is_file() else None)

    def points_and_displacement(self):
        vtu = meshio.read(self.folder / "fields.vtu")
        # iovtk writes coordinates as Float32 whatever floatmesh says; fields are Float64.
        return vtu.points[:, :2].astype(float), vtu.point_data["displacement"][:, :2]

    def contact_samples(self):
        return pd.read_csv(self.folder / "contact_pressure.csv")


def driver_run(case, out, *overrides):
    """python -m driver run CASE --out OUT --set ... -> Run, failing the test with the driver's message."""
    args = ["run", str(REPO / case), "--out", str(out)]
    for item in overrides:
        args += ["--set", item]
    proc = run_cli(*args)
    assert proc.returncode == 0, f"driver failed ({proc.returncode}):\n{proc.stderr}\n{proc.stdout}"
    return Run(out, proc.stdout)


@pytest.fixture
def run_scene(tmp_path):
    """run_scene(case, 'key=value', ...) -> Run, failing the test with the driver's message."""
    counter = iter(range(1000))
    return lambda case, *overrides: driver_run(case, tmp_path / f"run{next(counter)}", *overrides)


@pytest.fixture(scope="module")
def module_scene(tmp_path_factory):
    """module_scene(case, 'key=value', ...) -> Run as run_scene, each distinct run made
    once per test module (tests that read the same run share it)."""
    made = {}

    def _run(case, *overrides):
        key = (str(case), overrides)
        if key not in made:
            made[key] = driver_run(case, tmp_path_factory.mktemp("run"), *overrides)
        return made[key]

    return _run


def relative_max_error(values, exact):
    return float(np.abs(values - exact).max() / np.abs(exact).max())
