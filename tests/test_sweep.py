"""The Dask sweep runner (python -m driver sweep) on real LocalClusters, loopback only.

Coarse P1 points (NX = 16, well under a second of FreeFEM each); the tests that
interrupt or kill need slow points, made so by the sweep file's test hook
[debug] sleep_s (the task sleeps before FreeFEM starts). No test depends on a
timing threshold: waits are for events (a row file, a line of the attempts log)
with generous time limits.
"""

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pandas as pd
import pytest

from conftest import REPO, run_cli

BASE = REPO / "cases" / "disk_on_slab.toml"
COARSE = ["method.degree=1", "mesh.nx=16", "output.vtu=false", "output.pressure_csv=false"]


def write_sweep(folder, name, grid, zipped=None, debug=None, extra=""):
    lines = ["[sweep]", f'name = "{name}"', f'scene = "{BASE}"', f"set = {json.dumps(COARSE)}", extra,
             "[grid]"] + [f'"{k}" = {json.dumps(v)}' for k, v in grid.items()]
    if zipped:
        lines += ["[zip]"] + [f'"{k}" = {json.dumps(v)}' for k, v in zipped.items()]
    if debug:
        lines += ["[debug]"] + [f"{k} = {json.dumps(v)}" for k, v in debug.items()]
    path = Path(folder) / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def sweep_args(path, folder, *more):
    return ["sweep", str(path), "--results", str(folder), "--runs", str(Path(folder) / "state"), *more]


def attempts(folder):
    log = Path(folder) / "state" / "attempts.log"
    if not log.is_file():
        return []
    return [line.split() for line in log.read_text().splitlines() if line.strip()]


def row_files(folder):
    rows = Path(folder) / "state" / "rows"
    return {p.stem: p.read_text() for p in rows.glob("*.json")} if rows.is_dir() else {}


def wait_for(predicate, what, timeout=240):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def read_table(folder, name):
    return pd.read_csv(Path(folder) / f"sweep_{name}.csv")


@pytest.mark.freefem
def test_two_workers_give_the_rows_of_runs_one_by_one(tmp_path):
    """4 points (theta x gamma0) on 2 workers == the same points run one by one, in order."""
    from driver.sweep import load_sweep, points_of, scene_task

    path = write_sweep(tmp_path, "four", {"method.theta": [1, -1]}, zipped={"method.gamma0": [0.005, 0.05]})
    proc = run_cli(*sweep_args(path, tmp_path, "--workers", "2"))
    assert proc.returncode == 0, proc.stderr
    assert "4/4 done" in proc.stderr
    table = read_table(tmp_path, "four")
    table["message"] = table["message"].astype(object).fillna("")
    assert list(table["index"]) == [0, 1, 2, 3]
    assert (table.status == "converged").all()
    assert len(set(table.hash)) == 4
    assert table["method.theta"].tolist() == [1, 1, -1, -1]
    assert table["method.gamma0"].tolist() == [0.005, 0.05, 0.005, 0.05]
    assert len(set(table.host)) == 1 and table.theta.tolist() == [1, 1, -1, -1]

    varying = {"wall_s", "peak_rss_mb", "folder", "index", "hash", "host", "task_s"}
    for point, (_, row) in zip(points_of(load_sweep(path), tmp_path / "one_by_one"), table.iterrows()):
        single = scene_task(*point.args)
        assert single["status"] == "converged"
        assert set(single) - varying <= set(row.index)
        for key, value in single.items():
            if key not in varying:
                assert row[key] == (pytest.approx(value, rel=1e-12) if isinstance(value, float) else value), key
    # Run again: every point is stored, nothing runs (and no cluster starts).
    again = run_cli(*sweep_args(path, tmp_path, "--workers", "2"))
    assert again.returncode == 0, again.stderr
    assert "4/4 done (4 from earlier runs)" in again.stderr
    assert len(attempts(tmp_path)) == 4


@pytest.mark.freefem
def test_a_killed_worker_loses_no_row_and_its_point_is_retried(tmp_path):
    """SIGKILL the worker process running a point after some rows are stored."""
    path = write_sweep(tmp_path, "kill", {"mesh.nx": [12, 14, 16, 18, 20]}, debug={"sleep_s": 1.5})
    proc = subprocess.Popen([sys.executable, "-m", "driver", *sweep_args(path, tmp_path, "--workers", "2")],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        before = wait_for(lambda: row_files(tmp_path), "a first row")

        def started_unfinished():
            stored = row_files(tmp_path)
            return [a for a in attempts(tmp_path) if a[0] not in stored]

        victim_hash, _, pid, _ = wait_for(started_unfinished, "a running point")[0]
        before = row_files(tmp_path)
        os.kill(int(pid), signal.SIGKILL)
        out, err = proc.communicate(timeout=400)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    table = read_table(tmp_path, "kill")
    assert len(table) == 5 and (table.status == "converged").all(), table[["status", "message"]].to_dict("records")
    after = row_files(tmp_path)
    assert all(after[h] == text for h, text in before.items())      # no finished row lost or rewritten
    counts = Counter(a[0] for a in attempts(tmp_path))
    assert counts[victim_hash] == 2                                  # killed once, retried once
    assert sum(counts.values()) == 6


@pytest.mark.freefem
def test_failures_are_rows_and_a_point_that_keeps_killing_its_worker_is_bounded(tmp_path):
    """A Newton failure (exit 3) is a row, not a retry; a point whose task kills its worker
    every time is retried --max-retries times, then stored as a KilledWorker row."""
    path = write_sweep(tmp_path, "crash", {}, zipped={"mesh.nx": [12, 16, 20], "solver.newton_max": [30, 1, 30]},
                       debug={"crash_points": [2]})
    proc = run_cli(*sweep_args(path, tmp_path, "--workers", "2", "--max-retries", "1"))
    assert proc.returncode == 0, proc.stderr
    table = read_table(tmp_path, "crash")
    assert table.status.tolist() == ["converged", "NewtonError", "KilledWorker"]
    assert "newton" in table.message[1].lower()
    assert "KilledWorker" in proc.stdout and isinstance(table.message[2], str) and table.message[2]
    counts = Counter(a[0] for a in attempts(tmp_path))
    assert counts[table.hash[2]] == 2                          # the crash: first try + one retry
    # (the others ran once, plus once more for each death of a worker that still held their
    # finished result before the client fetched it: Dask then recomputes it; two deaths here)
    assert 1 <= counts[table.hash[0]] <= 3 and 1 <= counts[table.hash[1]] <= 3


@pytest.mark.freefem
def test_interrupted_sweep_resumes_running_each_point_once(tmp_path):
    """Ctrl-C after the first row: running points finish, the rest run on restart, once each."""
    path = write_sweep(tmp_path, "resume", {"mesh.nx": [12, 14, 16, 18, 20, 22]}, debug={"sleep_s": 1.5})
    # Its own process group, signalled as a whole, as a terminal's Ctrl-C does: the
    # workers and their FreeFEM runs must not die of it, only the client decides.
    proc = subprocess.Popen([sys.executable, "-m", "driver", *sweep_args(path, tmp_path, "--workers", "2")],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        wait_for(lambda: row_files(tmp_path), "a first row")
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted" in err
    stored = row_files(tmp_path)
    assert 1 <= len(stored) < 6
    assert set(stored) == {a[0] for a in attempts(tmp_path)}       # every started point finished
    assert len(read_table(tmp_path, "resume")) == len(stored)

    again = run_cli(*sweep_args(path, tmp_path, "--workers", "2"))
    assert again.returncode == 0, again.stderr
    assert f"6/6 done ({len(stored)} from earlier runs)" in again.stderr
    counts = Counter(a[0] for a in attempts(tmp_path))
    assert len(counts) == 6 and set(counts.values()) == {1}
    table = read_table(tmp_path, "resume")
    assert table["mesh.nx"].tolist() == [12, 14, 16, 18, 20, 22]
    assert (table.status == "converged").all()


@pytest.mark.parametrize("body, message", [
    ("[sweep\nscene = 1", "malformed TOML"),
    ('[sweep]\nscene = "BASE"\ncolour = 1\n[grid]\n"mesh.nx" = [8]', "unknown key 'sweep.colour'"),
    ('[sweep]\nscene = "BASE"\n[grids]\n"mesh.nx" = [8]', "unknown section or key 'grids'"),
    ('[sweep]\nscene = "BASE"\n[grid]\n"mesh.nx" = []', "empty list"),
    ('[sweep]\nscene = "BASE"\n', "empty grid"),
    ('[sweep]\nscene = "BASE"\n[zip]\n"mesh.nx" = [8, 10]\n"method.theta" = [1]', "unequal length"),
    ('[sweep]\nscene = "nowhere.toml"\n[grid]\n"mesh.nx" = [8]', "base scene 'nowhere.toml' not found"),
    ('[sweep]\nscene = "BASE"\n[grid]\n"mesh.nx" = [8, -1]', "point 1 (mesh.nx=-1)"),
    ('[sweep]\nscene = "BASE"\n[grid]\n"mesh.colour" = [8]', "mesh.colour"),
    ('[sweep]\nscene = "BASE"\n[grid]\n"mesh.nx" = 8', "expected a list"),
])
def test_bad_sweep_files_are_refused_before_anything_runs(tmp_path, capsys, body, message):
    path = tmp_path / "bad.toml"
    path.write_text(body.replace("BASE", str(BASE)))
    from driver.cli import main

    assert main(sweep_args(path, tmp_path)) == 2
    err = capsys.readouterr().err
    assert message in err and str(path) in err
    assert not list(tmp_path.glob("sweep_*.csv")) and not (tmp_path / "state").exists()


def test_smoke_sweep_file_expands_to_twelve_points():
    from driver.sweep import load_sweep

    sweep = load_sweep(REPO / "cases" / "sweeps" / "smoke.toml")
    assert len(sweep.params) == 12
    assert len({tuple(sorted(p.items())) for p in sweep.params}) == 12


@pytest.mark.parametrize("value", [
    [{"face": "ymax", "displacement": [0.0, -0.004]}],
    {"type": "difference", "of": [{"type": "disk", "centre": [0.0, 0.0], "radius": 0.25},
                                  {"type": "box", "min": [-0.1, -0.1], "max": [0.1, 0.1], "corner_radius": 0.02}]},
    [1, 2.5e-3, "a \"quoted\" name", True, float("inf")],
])
def test_sweep_values_may_be_tables(value):
    """A sweep varies supports and shapes too (an indentation depth, a hole's size): a
    grid value is written as the --set literal that parses back to the same value."""
    from driver.scene import parse_override
    from driver.sweep import toml_literal

    assert parse_override("body1.hold=" + toml_literal(value)) == (["body1", "hold"], value)
