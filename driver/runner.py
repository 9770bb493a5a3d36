"""Launch FreeFEM on a scene, each run in its own folder, published atomically.

FreeFEM writes into a staging folder runs/.staging/ID; the folder is renamed to
runs/ID only when the run converged and its results.json parses, otherwise to
runs/ID.failed (which holds failure.json and the log, never results.json).
"""

import datetime
import hashlib
import json
import os
import re
import shutil
import subprocess
import threading
import time
from pathlib import Path

from driver.errors import FreeFemError, NewtonError, SceneError

REPO = Path(__file__).resolve().parent.parent
FREEFEM_DIR = REPO / "freefem"
PLUGIN_DIR = "/usr/lib/freefem++"


def freefem_env():
    env = dict(os.environ)
    env["FF_LOADPATH"] = PLUGIN_DIR   # Debian's binary looks in the wrong folder
    # One BLAS thread: FreeFEM phases are timed with CPU clock() (see results.idp).
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = "1"
    return env


def freefem_binary():
    path = shutil.which("FreeFem++")
    if path is None:
        raise FreeFemError("FreeFem++ not found on PATH: run 'make setup' "
                           "(Debian packages freefem++ libfreefem++)")
    return path


def run_command(command, what, cwd=None, log=None):
    """Run a helper program (gmsh); raise FreeFemError with its output on failure."""
    proc = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = (proc.stdout + proc.stderr).strip().splitlines()[-15:]
        raise FreeFemError(f"{what} failed (exit {proc.returncode}):\n  " + "\n  ".join(tail))
    return proc


def parse_json_file(path):
    """FreeFEM prints non-finite numbers as nan/inf: map them before parsing."""
    text = Path(path).read_text()
    text = re.sub(r"(?<![\w\"])-?nan(?![\w\"])", "NaN", text)
    text = re.sub(r"(?<![\w\"])(-?)inf(?![\w\"])", r"\1Infinity", text)
    return json.loads(text)


def freefem_message(log_text):
    """The lines of a FreeFEM log that explain a failure."""
    keep = [line for line in log_text.splitlines()
            if re.search(r"error|INPUT ERROR|NEWTON FAILURE|Exec|exception|line number", line, re.I)]
    return "\n  ".join(keep[-8:]) if keep else "\n  ".join(log_text.strip().splitlines()[-8:])


def watch_peak_memory(pid, result):
    """Poll the kernel's high-water mark of a process (VmHWM, kB) until it exits."""
    path = Path(f"/proc/{pid}/status")
    while True:
        try:
            for line in path.read_text().splitlines():
                if line.startswith("VmHWM:"):
                    result[0] = max(result[0], int(line.split()[1]))
        except (OSError, ValueError):
            return
        time.sleep(0.05)


def run_id(scene, args):
    digest = hashlib.sha1(" ".join(args).encode()).hexdigest()[:8]
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return f"{scene['scene']['name']}-{stamp}-{digest}"


def run_scene(scene, module, runs_dir=None, out_dir=None, script=None, echo=None):
    """Run FreeFEM for a validated scene. Returns (results dict, run folder, wall seconds)."""
    runs_dir = Path(runs_dir or REPO / "runs")
    script = Path(script) if script else FREEFEM_DIR / f"{scene['scene']['script']}.edp"
    if not script.is_file():
        raise SceneError(f"{scene['_source']}: FreeFEM script not found: {script}")
    binary = freefem_binary()
    probe_args = module.freefem_args(scene)
    final = Path(out_dir) if out_dir else runs_dir / run_id(scene, probe_args)
    staging = final.parent / ".staging" / final.name   # same filesystem: rename is atomic
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    (staging / "scene.json").write_text(json.dumps(
        {k: v for k, v in scene.items() if not k.startswith("_")}, indent=2, default=str))

    try:
        mesh_file = module.prepare_mesh(scene, staging, run_command)
        args = module.freefem_args(scene, mesh_file=mesh_file)
    except FreeFemError:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    # -Dmacro flags must follow the script name; everything else is -key value.
    command = [binary, "-nw", "-v", "0", str(script)] + args + ["-outdir", str(staging)]
    # FreeFEM's output is block-buffered on a pipe: line-buffer it for progress.
    stdbuf = shutil.which("stdbuf")
    launch = [stdbuf, "-oL", "-eL"] + command if stdbuf else command
    (staging / "command.txt").write_text(" ".join(command) + "\n")
    start = time.perf_counter()
    with open(staging / "freefem.log", "w") as log:
        proc = subprocess.Popen(launch, cwd=REPO, env=freefem_env(), stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        peak_kb = [0]
        watcher = threading.Thread(target=watch_peak_memory, args=(proc.pid, peak_kb), daemon=True)
        watcher.start()
        for line in proc.stdout:
            log.write(line)
            if echo is not None:
                echo(line.rstrip("\n"))
        proc.wait()
    wall = time.perf_counter() - start
    log_text = (staging / "freefem.log").read_text()
    name = scene["scene"]["name"]

    def fail(error):
        (staging / "results.json").unlink(missing_ok=True)
        failed = final.with_name(final.name + ".failed")
        if failed.exists():
            shutil.rmtree(failed)
        staging.rename(failed)
        error.args = (f"{error.args[0]}\n  (log and inputs kept in {failed})",)
        raise error

    if proc.returncode == 3 and (staging / "failure.json").is_file():
        failure = parse_json_file(staging / "failure.json")
        fail(NewtonError(f"scene {name}: {failure.get('message', 'Newton failure')} "
                         f"(last residual {failure.get('last_residual')})"))
    if proc.returncode == 2 and "INPUT ERROR" in log_text:
        fail(SceneError(f"scene {name}: FreeFEM rejected the input:\n  {freefem_message(log_text)}"))
    if proc.returncode != 0:
        fail(FreeFemError(f"scene {name}: FreeFEM failed (exit {proc.returncode}):\n  "
                          f"{freefem_message(log_text)}"))
    results_path = staging / "results.json"
    if not results_path.is_file():
        fail(FreeFemError(f"scene {name}: FreeFEM exited normally but wrote no results.json"))
    try:
        results = parse_json_file(results_path)
    except (ValueError, OSError) as exc:
        fail(FreeFemError(f"scene {name}: results.json is unreadable ({exc})"))
    if results.get("status") != "converged":
        fail(NewtonError(f"scene {name}: run status is {results.get('status')!r}"))
    results["wall_s"] = wall
    results["peak_rss_mb"] = peak_kb[0] / 1024.0
    results_path.write_text(json.dumps(results, indent=1))
    if final.exists():
        shutil.rmtree(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    staging.rename(final)
    return results, final, wall


def run_freefem_tool(script, args, output, what):
    """Run a post-processing script (errors, comparisons) that writes one JSON file."""
    output = Path(output)
    output.unlink(missing_ok=True)
    command = [freefem_binary(), "-nw", "-v", "0", str(FREEFEM_DIR / script)] + list(args)
    proc = subprocess.run(command, cwd=REPO, env=freefem_env(), capture_output=True, text=True)
    if proc.returncode != 0 or not output.is_file():
        raise FreeFemError(f"{what} failed (exit {proc.returncode}):\n  "
                           f"{freefem_message(proc.stdout + proc.stderr)}")
    return parse_json_file(output)
