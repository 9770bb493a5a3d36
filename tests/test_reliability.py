"""Safe with any input: no shell, no lost data, clean failures, strict direct runs.

Each test reproduces a reported failure and checks the promised outcome (README,
"Reliability"): the exit code, one clear error line, and the files left behind.
"""

import json
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import REPO, run_cli, run_freefem

DISK = REPO / "cases" / "disk_on_slab.toml"
BALL = REPO / "cases" / "ball_on_slab.toml"
SMALL = ["--set", "mesh.nx=16", "--set", "method.degree=1", "--set", "output.estimators=false"]


def error_lines(proc):
    return [line for line in proc.stderr.splitlines() if line.startswith("error:")]


def printed(proc):
    """FreeFEM sends its cerr to stdout as well: look at both."""
    return proc.stdout + proc.stderr


def scene_copy(tmp_path, text_changes=(), name="scene.toml"):
    text = DISK.read_text()
    for old, new in text_changes:
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text)
    return path


# ---- no shell ---------------------------------------------------------------------------

def test_scene_name_with_shell_characters_is_refused(tmp_path):
    scene = scene_copy(tmp_path, [('name = "disk_on_slab"', 'name = "x\'; touch PWNED; echo \'"')])
    proc = run_cli("run", str(scene), *SMALL, cwd=tmp_path)
    assert proc.returncode == 2
    assert "scene.name" in proc.stderr and len(error_lines(proc)) == 1
    assert not (tmp_path / "PWNED").exists() and not (REPO / "PWNED").exists()


def test_scene_name_cannot_leave_runs(tmp_path):
    scene = scene_copy(tmp_path, [('name = "disk_on_slab"', 'name = "../../escape"')])
    proc = run_cli("run", str(scene), *SMALL)
    assert proc.returncode == 2 and "scene.name" in proc.stderr
    assert not (REPO.parent / "escape").exists()


@pytest.mark.freefem
def test_out_with_quotes_and_semicolons_is_just_a_folder_name(tmp_path):
    out = tmp_path / "it's; touch PWNED; echo '"
    proc = run_cli("run", str(DISK), *SMALL, "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert json.loads((out / "results.json").read_text())["status"] == "converged"
    assert not (tmp_path / "PWNED").exists() and not (REPO / "PWNED").exists()


@pytest.mark.freefem
def test_direct_run_outdir_and_name_never_reach_a_shell(tmp_path):
    out = tmp_path / "a b'; touch PWNED; echo '"
    proc = run_freefem("fd_contact_2d.edp", "-Ddegree=1", "-nx", 12, "-estimators", 0, "-outdir", out)
    assert proc.returncode == 0, proc.stderr
    assert (out / "results.json").is_file()
    proc = run_freefem("fd_contact_2d.edp", "-nx", 12, "-name", "x';touch PWNED;'")
    assert proc.returncode == 2 and "not a safe name" in printed(proc)
    assert not (REPO / "PWNED").exists() and not (tmp_path / "PWNED").exists()


def test_no_freefem_file_calls_a_shell():
    calls = []
    for path in sorted((REPO / "freefem").rglob("*.[ei]dp")):
        calls += [path.name for line in path.read_text().splitlines() if "exec(" in line or "system(" in line]
    assert calls == []


# ---- no lost data -----------------------------------------------------------------------

def test_out_on_a_user_folder_is_refused_and_left_untouched(tmp_path):
    out = tmp_path / "thesis"
    out.mkdir()
    (out / "thesis.txt").write_text("three years of work")
    proc = run_cli("run", str(DISK), *SMALL, "--out", str(out))
    assert proc.returncode == 2 and "not a run of this package" in proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["thesis.txt"]
    assert (out / "thesis.txt").read_text() == "three years of work"


@pytest.mark.parametrize("where", ["checkout", "parent", "home", "dot"])
def test_out_on_the_checkout_its_parents_or_home_is_refused(where, tmp_path):
    out = {"checkout": str(REPO), "parent": str(REPO.parent), "home": str(Path.home()), "dot": "."}[where]
    proc = run_cli("run", str(DISK), *SMALL, "--out", out)
    assert proc.returncode == 2 and "refusing" in proc.stderr
    assert (REPO / ".git").exists() and (REPO / "freefem").is_dir()


@pytest.mark.freefem
def test_replacing_a_run_needs_the_flag_and_a_failed_run_leaves_it_intact(tmp_path):
    out = tmp_path / "R"
    assert run_cli("run", str(DISK), *SMALL, "--out", str(out)).returncode == 0
    first = (out / "results.json").read_text()
    again = run_cli("run", str(DISK), *SMALL, "--out", str(out))
    assert again.returncode == 2 and "--replace" in again.stderr
    failing = run_cli("run", str(DISK), *SMALL, "--set", "solver.newton_max=1", "--out", str(out), "--replace")
    assert failing.returncode == 3
    assert f"{out} is unchanged" in failing.stderr
    assert (out / "results.json").read_text() == first
    failed = tmp_path / "R.failed"
    assert (failed / "failure.json").is_file() and not (failed / "results.json").exists()
    replaced = run_cli("run", str(DISK), *SMALL, "--set", "method.theta=0", "--out", str(out), "--replace")
    assert replaced.returncode == 0
    assert json.loads((out / "results.json").read_text())["theta"] == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.freefem
def test_a_failed_run_into_a_new_folder_writes_no_results(tmp_path):
    out = tmp_path / "R"
    proc = run_cli("run", str(DISK), *SMALL, "--set", "solver.newton_max=1", "--out", str(out))
    assert proc.returncode == 3 and len(error_lines(proc)) == 1
    assert not out.exists()
    assert not (tmp_path / "R.failed" / "results.json").exists()


@pytest.mark.freefem
def test_a_second_writer_to_the_same_folder_is_refused(tmp_path):
    out = tmp_path / "R"
    first = subprocess.Popen([sys.executable, "-m", "driver", "run", str(DISK), "--set", "mesh.nx=120",
                              "--out", str(out)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    staging = tmp_path / ".R.staging"
    deadline = time.time() + 30
    while not (staging / "freefem.log").exists() and time.time() < deadline:
        time.sleep(0.05)
    second = run_cli("run", str(DISK), *SMALL, "--out", str(out))
    _, first_err = first.communicate(timeout=300)
    assert first.returncode == 0, first_err
    assert second.returncode == 2 and "another run is writing" in second.stderr
    assert json.loads((out / "results.json").read_text())["nx"] == 120


@pytest.mark.freefem
def test_relative_out_is_relative_to_the_working_folder(tmp_path):
    proc = run_cli("run", str(DISK), *SMALL, "--out", "rel", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "rel" / "results.json").is_file()


# ---- clean failures ---------------------------------------------------------------------

@pytest.mark.parametrize("content", [b"\x00\x01\x02binary\xff", "name = 'caf\u00e9'\n".encode("latin-1")])
def test_binary_or_undecodable_scene_and_sweep_files(content, tmp_path):
    path = tmp_path / "bad.toml"
    path.write_bytes(content)
    for command in (["run", str(path)], ["sweep", str(path)]):
        proc = run_cli(*command)
        assert proc.returncode == 2, proc.stderr
        assert "Traceback" not in proc.stderr and len(error_lines(proc)) == 1
        assert "binary" in proc.stderr or "UTF-8" in proc.stderr


def test_a_run_too_large_for_the_machine_is_refused_before_it_starts(tmp_path):
    # the largest mesh.nx the schema allows: P2, about 6e7 DOFs and 400 GiB estimated
    proc = run_cli("run", str(DISK), "--set", "mesh.nx=4000", "--out", str(tmp_path / "R"))
    assert proc.returncode == 2 and "too large for this machine" in proc.stderr
    assert "DOFs" in proc.stderr and "GiB" in proc.stderr
    assert not any(tmp_path.iterdir())


def limit_file_size(limit_bytes):
    def apply():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # writes then fail with EFBIG, as on a full disk
    return apply


def test_a_full_disk_gives_one_line_and_no_results(tmp_path):
    out = tmp_path / "R"
    proc = subprocess.run([sys.executable, "-m", "driver", "run", str(DISK), "--set", "mesh.nx=40",
                           "--out", str(out)], cwd=REPO, capture_output=True, text=True,
                          preexec_fn=limit_file_size(64 * 1024))
    assert proc.returncode == 4, proc.stderr
    assert "Traceback" not in proc.stderr and len(error_lines(proc)) == 1
    assert not out.exists()


@pytest.mark.freefem
def test_a_direct_run_that_cannot_write_its_results_fails(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run(["FreeFem++", "-nw", "-v", "0", "freefem/fd_contact_2d.edp", "-nx", "40",
                           "-outdir", str(out)], cwd=REPO, capture_output=True, text=True,
                          preexec_fn=limit_file_size(64 * 1024))
    assert proc.returncode == 4 and "OUTPUT ERROR" in printed(proc)
    assert not (out / "results.json").exists()
    assert not (out / "fields.vtu").exists()


@pytest.mark.freefem
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_an_interrupted_run_stops_freefem_and_keeps_no_results(signum, tmp_path):
    out = tmp_path / "R"
    proc = subprocess.Popen([sys.executable, "-m", "driver", "run", str(DISK), "--set", "mesh.nx=200",
                             "--out", str(out)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    log = tmp_path / ".R.staging" / "freefem.log"
    deadline = time.time() + 30
    while not (log.exists() and log.stat().st_size > 0) and time.time() < deadline:   # FreeFEM prints
        time.sleep(0.05)
    command = (log.parent / "command.txt").read_text().split()
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signum
    assert f"interrupted by {signal.Signals(signum).name}" in err and "Traceback" not in err
    assert not out.exists() and not log.parent.exists()
    assert json.loads((tmp_path / "R.failed" / "failure.json").read_text())["status"] == "failed"
    outdir = command[command.index("-outdir") + 1]
    running = subprocess.run(["pgrep", "-f", outdir], capture_output=True, text=True).stdout.split()
    assert running == []


# ---- direct FreeFEM runs are as strict as the driver ------------------------------------

@pytest.mark.freefem
@pytest.mark.parametrize("args, message", [
    (["-thetaa", "1"], "unknown option '-thetaa'"),
    (["-gama0", "1"], "unknown option '-gama0'"),
    (["-nx"], "option -nx needs a value"),
    (["-nx", "0"], "option -nx: 0 must lie in [2, 4000]"),
    (["-nx", "2.5"], "not an integer"),
    (["-theta", "nan"], "not a number"),
    (["-gamma0", "1e999"], "not a finite number"),
    (["-fix_ay", "0.9"], "the fixing points fix_a, fix_b must lie inside body 1"),
    (["-disk_cx", "0.4"], "unknown option '-disk_cx'"),      # the geometry is the scene module's
])
def test_direct_2d_run_refuses_bad_options(args, message):
    proc = run_freefem("fd_contact_2d.edp", *args)
    assert proc.returncode == 2, printed(proc)
    assert "INPUT ERROR" in printed(proc) and message in printed(proc)


@pytest.mark.freefem
@pytest.mark.parametrize("args, message", [
    (["-thetaa", "1"], "unknown option '-thetaa'"),
    (["-fix_az", "0.4"], "a fixing point lies outside body 1's submesh"),
    (["-ball_cz", "-0.1"], "unknown option '-ball_cz'"),     # the geometry is the scene module's
])
def test_direct_3d_run_refuses_bad_options(args, message):
    proc = run_freefem("fd_contact_3d.edp", *args)
    assert proc.returncode == 2 and message in printed(proc)


@pytest.mark.freefem
@pytest.mark.parametrize("script", ["fd_contact_2d.edp", "fd_contact_3d.edp", "contact_foundation_2d.edp"])
def test_direct_run_refuses_a_degree_other_than_1_or_2(script):
    proc = run_freefem(script, "-Ddegree=3")
    assert proc.returncode != 0 and "-Ddegree must be 1 or 2" in printed(proc)


@pytest.mark.freefem
@pytest.mark.parametrize("override, freefem_args", [
    ("body2.top=0.9", ["-slab_top", "0.9"]),
    ("body2.top=0.1", ["-slab_top", "0.1"]),
    ("body1.centre=[0.4, 0.0]", ["-disk_cx", "0.4"]),
    ("geometry.xmax=-0.6", ["-xmax", "-0.6"]),
])
def test_driver_and_direct_run_refuse_the_same_scenes(override, freefem_args, tmp_path):
    proc = run_cli("run", str(DISK), "--set", override, "--out", str(tmp_path / "R"))
    assert proc.returncode == 2, proc.stderr
    direct = run_freefem("fd_contact_2d.edp", *freefem_args, "-outdir", tmp_path / "direct")
    assert direct.returncode == 2, printed(direct)
    assert not (tmp_path / "direct" / "results.json").exists()

