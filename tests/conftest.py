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


class Run:
    def __init__(self, folder, summary=""):
        self.folder = Path(folder)
        self.results = json.loads((self.folder / "results.json").read_text())
        self.summary = summary      # what the driver printed (its summary), when run by it

    def points_and_displacement(self):
        vtu = meshio.read(self.folder / "fields.vtu")
        # iovtk writes coordinates as Float32 whatever floatmesh says; fields are Float64.
        return vtu.points[:, :2].astype(float), vtu.point_data["displacement"][:, :2]

    def contact_samples(self):
        return pd.read_csv(self.folder / "contact_pressure.csv")


@pytest.fixture
def run_scene(tmp_path):
    """run_scene(case, 'key=value', ...) -> Run, failing the test with the driver's message."""
    counter = iter(range(1000))

    def _run(case, *overrides):
        out = tmp_path / f"run{next(counter)}"
        args = ["run", str(REPO / case), "--out", str(out)]
        for item in overrides:
            args += ["--set", item]
        proc = run_cli(*args)
        assert proc.returncode == 0, f"driver failed ({proc.returncode}):\n{proc.stderr}\n{proc.stdout}"
        return Run(out, proc.stdout)

    return _run


def relative_max_error(values, exact):
    return float(np.abs(values - exact).max() / np.abs(exact).max())
