"""Runs on several MPI processes (solver.ranks): FreeFem++-mpi under mpirun, the Newton's
factorizations and solves distributed by parallel MUMPS through the plugin built for it
(freefem/plugins/mpi/contact_mumps.so, docs/design.md). The answer is the one-process
answer to solver round-off; a process that dies stops the run with one line."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, relative_max_error
from driver.runner import process_tree

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM

BALL = "cases/ball_on_slab.toml"
SMALL = ("method.degree=2", "mesh.nx=8", "output.vtu=false")   # 6,126 DOFs


def relative(reference, value):
    """The largest difference from the reference, relative to its largest magnitude."""
    return relative_max_error(np.asarray(value, float), np.asarray(reference, float))


def test_two_processes_give_the_one_process_answer(module_scene):
    one = module_scene(BALL, *SMALL)
    two = module_scene(BALL, *SMALL, "solver.ranks=2")
    # the same Newton path, the answers to round-off (measured: centre 1.0e-14, force
    # 2.4e-13, pressure 6.5e-13 and recovered 2.5e-12 of their largest value)
    assert two.results["newton"]["iterations"] == one.results["newton"]["iterations"]
    assert relative(one.results["probes"]["centre"], two.results["probes"]["centre"]) < 1e-13
    assert relative(one.results["contact"]["force_on_body1"], two.results["contact"]["force_on_body1"]) < 2e-12
    p1, p2 = one.contact_samples(), two.contact_samples()
    assert relative(p1.pressure, p2.pressure) < 5e-12
    assert relative(p1.pressure_recovered, p2.pressure_recovered) < 2e-11
    # each process's peak memory in results.json (one process: the driver's peak_rss_mb)
    assert one.results["newton"]["processes"] == 1 and "process_peak_mb" not in one.results["newton"]
    peaks = two.results["newton"]["process_peak_mb"]
    assert two.results["newton"]["processes"] == 2 and len(peaks) == 2 and min(peaks) > 10
    # rank 1 holds a share of the factors only, rank 0 the script's data too
    assert peaks[1] < peaks[0]


def test_direct_mpirun_run_gives_the_driver_answer(module_scene, tmp_path):
    # ff-mpirun -np 2 freefem/fd_contact_3d.edp ...: the script's own defaults are the ball on slab
    out = tmp_path / "direct"
    env = dict(os.environ, FF_LOADPATH="/usr/lib/freefem++", OMPI_ALLOW_RUN_AS_ROOT="1",
               OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run(["ff-mpirun", "-np", "2", "freefem/fd_contact_3d.edp", "-Ddegree=2", "-nx", "8",
                           "-vtu", "0", "-outdir", str(out)], cwd=REPO, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    driver = module_scene(BALL, *SMALL, "solver.ranks=2")
    direct = json.loads((out / "results.json").read_text())
    assert direct["newton"]["processes"] == 2
    assert relative(direct["probes"]["centre"], driver.results["probes"]["centre"]) < 1e-13


def rank_of(pid):
    try:
        environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    except OSError:
        return None
    for item in environ:
        if item.startswith(b"OMPI_COMM_WORLD_RANK="):
            return int(item.split(b"=")[1])
    return None


def test_a_dead_rank_stops_the_run_with_one_line(tmp_path):
    args = [sys.executable, "-m", "driver", "run", BALL, "--out", str(tmp_path / "run"),
            "--set", "method.degree=2 mesh.nx=12 output.vtu=false solver.ranks=2"]
    driver = subprocess.Popen(args, cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    victim, deadline = None, time.monotonic() + 60
    while victim is None and driver.poll() is None and time.monotonic() < deadline:
        for pid in process_tree(driver.pid):
            if rank_of(pid) == 1 and b"FreeFem++-mpi" in Path(f"/proc/{pid}/cmdline").read_bytes():
                victim = pid
        time.sleep(0.05)
    assert victim is not None, "rank 1 never started"
    os.kill(victim, signal.SIGKILL)
    out, err = driver.communicate(timeout=120)
    assert driver.returncode == 4
    first = err.strip().splitlines()[0]
    assert first.startswith("error: scene ball_on_slab: MPI rank 1 of 2 (node ")
    assert "died on signal 9 (Killed), out of memory?: mpirun stopped the whole run" in first
    assert not (tmp_path / "run").exists() and (tmp_path / "run.failed").is_dir()


def test_block_low_rank_factors_give_the_full_rank_answer(module_scene):
    # solver.compression: MUMPS's BLR factors (MPI build: the driver starts mpirun on one
    # process), refined to double precision like single-precision factors. MUMPS
    # compresses only large fronts: at nx = 8 (6,126 DOFs) nothing is compressed, at
    # nx = 14 (30,528 DOFs) 0.79 of the entries are kept.
    larger = ("method.degree=2", "mesh.nx=14", "output.vtu=false", "output.estimators=false")
    full = module_scene(BALL, *larger)
    blr = module_scene(BALL, *larger, "solver.compression=1e-4")
    n = blr.results["newton"]
    assert n["processes"] == 1 and n["compression"] == 1e-4
    assert n["factor_entries_compressed"] < 0.85*n["factor_entries"]
    assert n["refinement_steps"] > full.results["newton"]["refinement_steps"]
    # measured: centre 1.2e-14, pressure 1.6e-12 of their largest value
    assert relative(full.results["probes"]["centre"], blr.results["probes"]["centre"]) < 1e-13
    assert relative(full.contact_samples().pressure, blr.contact_samples().pressure) < 1e-11
