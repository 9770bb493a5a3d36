"""Launch FreeFEM on a scene, each run in its own folder, published atomically.

FreeFEM writes into a hidden staging folder .ID.staging beside the run folder ID
(runs/ID by default, or --out); the staging folder is renamed to ID only when the
run converged and its results.json parses, otherwise to ID.failed (which holds
failure.json and the log, never results.json). See check_output_folder for what
an --out may be.
"""

import datetime
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

from driver.errors import DriverError, FreeFemError, NewtonError, SceneError
from driver.resources import check_fits

REPO = Path(__file__).resolve().parent.parent
FREEFEM_DIR = REPO / "freefem"
TOOLS_DIR = FREEFEM_DIR / "tools"     # error measures and cross-checks (run_freefem_tool)
PLUGIN_DIR = "/usr/lib/freefem++"


def freefem_env():
    env = dict(os.environ)
    env["FF_LOADPATH"] = PLUGIN_DIR   # Debian's binary looks in the wrong folder
    # One BLAS thread: FreeFEM phases are timed with CPU clock() (see freefem/lib/core/results.idp).
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


# Every folder the driver creates holds this file: the driver only ever replaces or
# removes folders that carry it.
MARKER = ".fdcontact-run"


def is_package_run(folder):
    """A folder this package wrote (runs made before the marker existed: their three inputs)."""
    return (folder / MARKER).is_file() or all(
        (folder / name).is_file() for name in ("scene.json", "command.txt", "freefem.log"))


def check_output_folder(final, replace):
    """Refuse an --out that would lose data: a place that is not a run of this package,
    a previous run without replace=True, the checkout, its parents, the home folder."""
    protected = {Path("/"), Path.home().resolve(), REPO}
    if final in protected or final in REPO.parents or final in Path.home().resolve().parents:
        raise SceneError(f"--out {final}: refusing to write a run into the checkout, its parent folders "
                         f"or the home folder; name a new folder")
    if final.is_symlink() or (final.exists() and not final.is_dir()):
        raise SceneError(f"--out {final}: exists and is not a folder")
    if final.is_dir():
        if is_package_run(final):
            if (final / "results.json").is_file() and not replace:
                raise SceneError(f"--out {final}: holds a previous run; pass --replace to replace it "
                                 f"(the old run stays until the new one has converged)")
        elif any(final.iterdir()):
            raise SceneError(f"--out {final}: exists and is not a run of this package; "
                             f"name a new or empty folder (nothing in it was touched)")


def pid_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def claim_staging(staging, final):
    """Create the staging folder exclusively: one writer per output folder."""
    staging.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(2):
        try:
            staging.mkdir()
        except FileExistsError:
            try:
                owner = int((staging / "driver.pid").read_text())
            except (OSError, ValueError):
                owner = None
            if owner is not None and pid_alive(owner) or not is_package_run(staging):
                raise SceneError(f"--out {final}: another run is writing to it"
                       + (f" (driver pid {owner})" if owner else f" ({staging} exists)"))
            shutil.rmtree(staging)   # left by a driver that was killed
            continue
        (staging / MARKER).write_text("fdcontact run folder\n")
        (staging / "driver.pid").write_text(f"{os.getpid()}\n")
        return
    raise SceneError(f"--out {final}: could not claim {staging}")


def failed_folder(final):
    """Where a failed run's log goes: FINAL.failed, or FINAL.failed-2, -3, ... beside
    earlier failures (a run deletes nothing it did not create)."""
    for k in range(1, 1000):
        failed = final.with_name(final.name + (".failed" if k == 1 else f".failed-{k}"))
        if not failed.exists():
            return failed
    raise SceneError(f"{final}: 999 failed runs beside it; remove some")


def publish(staging, final):
    """Move the finished run into place; a previous run is removed only after that."""
    old = None
    if final.is_dir():
        old = final.with_name(f".{final.name}.replaced-{os.getpid()}")
        final.rename(old)
    staging.rename(final)
    if old is not None:
        if is_package_run(old):
            shutil.rmtree(old)
        else:
            old.rmdir()   # the empty folder the user named


class Interrupted(Exception):
    """SIGINT or SIGTERM during a run (raised by the command line's signal handler)."""

    def __init__(self, signum, detail=""):
        super().__init__(signum)
        self.signum = signum
        self.detail = detail


def stop_process(proc):
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run_scene(scene, module, runs_dir=None, out_dir=None, script=None, echo=None, replace=False):
    """Run FreeFEM for a validated scene. Returns (results dict, run folder, wall seconds).

    FreeFEM writes into a hidden staging folder beside the run folder, claimed
    exclusively; the staging folder becomes the run folder only when the run
    converged and its results.json parses, otherwise FINAL.failed (its log,
    failure.json, never results.json). The run folder itself is left as it was.
    """
    runs_dir = Path(runs_dir or REPO / "runs").resolve()
    script = Path(script) if script else FREEFEM_DIR / f"{scene['scene']['script']}.edp"
    if not script.is_file():
        raise SceneError(f"{scene['_source']}: FreeFEM script not found: {script}")
    binary = freefem_binary()
    probe_args = module.freefem_args(scene)
    if out_dir:
        final = Path(out_dir).expanduser().resolve()
    else:
        base = runs_dir / run_id(scene, probe_args)
        final, k = base, 1
        while final.exists() or final.with_name(f".{final.name}.staging").exists():
            k += 1
            final = base.with_name(f"{base.name}-{k}")
    check_output_folder(final, replace)
    check_fits(scene, scene["_source"])
    staging = final.with_name(f".{final.name}.staging")   # same filesystem: rename is atomic
    claim_staging(staging, final)
    proc = None
    try:
        (staging / "scene.json").write_text(json.dumps(
            {k: v for k, v in scene.items() if not k.startswith("_")}, indent=2, default=str))
        mesh_file = module.prepare_mesh(scene, staging, run_command)
        args = module.freefem_args(scene, mesh_file=mesh_file)
        entry = write_scene_module(scene, module, script, staging)
        # -Dmacro flags must follow the script name; everything else is -key value.
        command = [binary, "-nw", "-v", "0", str(entry)] + args + ["-outdir", str(staging)]
        # FreeFEM's output is block-buffered on a pipe: line-buffer it for progress.
        stdbuf = shutil.which("stdbuf")
        launch = [stdbuf, "-oL", "-eL"] + command if stdbuf else command
        (staging / "command.txt").write_text(" ".join(command) + "\n")
        start = time.perf_counter()
        with open(staging / "freefem.log", "w") as log:
            proc = subprocess.Popen(launch, cwd=REPO, env=freefem_env(), stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True, errors="replace")
            peak_kb = [0]
            watcher = threading.Thread(target=watch_peak_memory, args=(proc.pid, peak_kb), daemon=True)
            watcher.start()
            for line in proc.stdout:
                log.write(line)
                log.flush()   # the log of a running job can be followed (tail -f)
                if echo is not None:
                    echo(line.rstrip("\n"))
            proc.wait()
        wall = time.perf_counter() - start
        results = check_outcome(proc.returncode, staging, scene["scene"]["name"])
        results["wall_s"] = wall
        results["peak_rss_mb"] = peak_kb[0] / 1024.0
        (staging / "results.json").write_text(json.dumps(results, indent=1))
        (staging / "driver.pid").unlink()
        publish(staging, final)
        return results, final, wall
    except BaseException as error:
        if proc is not None:
            stop_process(proc)
        if isinstance(error, Interrupted | KeyboardInterrupt):
            signum = error.signum if isinstance(error, Interrupted) else signal.SIGINT
            error = Interrupted(signum)
            reason = f"interrupted by {signal.Signals(signum).name}"
        elif isinstance(error, OSError):
            reason = f"{error.strerror or error} ({error.filename or staging})"
            error = FreeFemError(f"scene {scene['scene']['name']}: cannot write the run: {reason}")
        else:
            reason = str(error.args[0]) if error.args else type(error).__name__
        keep_failure(staging, final, error, reason)
        raise error from None


def write_scene_module(scene, module, script, staging):
    """The script FreeFEM runs: for a scene with a scene module (docs/scene-modules.md),
    run.edp in the run folder, which includes scene.idp (beside it) and then the solver
    (from the repository root, FreeFEM's working folder); else the solver itself."""
    make = getattr(module, "scene_module", None)
    if make is None:
        return script
    (staging / "scene.idp").write_text(make(scene))
    script = script.resolve()
    name = script.relative_to(REPO).as_posix() if script.is_relative_to(REPO) else str(script)
    if '"' in name or "\n" in name:
        raise SceneError(f"{script}: a script path for FreeFEM's include must not hold quotes or line breaks")
    (staging / "run.edp").write_text(f'include "scene.idp"   // the scene (written by the driver)\n'
                                     f'include "{name}"\n')
    return staging / "run.edp"


def keep_failure(staging, final, error, reason):
    """Turn the staging folder into FINAL.failed (never with a results.json); name it in the error."""
    try:
        (staging / "results.json").unlink(missing_ok=True)
        (staging / "driver.pid").unlink(missing_ok=True)
        if not (staging / "failure.json").is_file():
            (staging / "failure.json").write_text(json.dumps({"status": "failed", "message": reason}) + "\n")
        failed = failed_folder(final)
        staging.rename(failed)
        where = f"log and inputs kept in {failed}"
    except OSError:
        shutil.rmtree(staging, ignore_errors=True)
        where = "nothing kept"
    unchanged = " is unchanged" if final.exists() else " was not created"
    if isinstance(error, DriverError):
        error.args = (f"{error.args[0]}\n  ({where}; {final}{unchanged})",)
    elif isinstance(error, Interrupted):
        error.detail = f"FreeFEM stopped; {where}; {final}{unchanged}"


def check_outcome(returncode, staging, name):
    """Map FreeFEM's exit and files to a result dict or a DriverError."""
    log_text = (staging / "freefem.log").read_text(errors="replace")
    if returncode == 3 and (staging / "failure.json").is_file():
        failure = parse_json_file(staging / "failure.json")
        raise NewtonError(f"scene {name}: {failure.get('message', 'Newton failure')} "
                          f"(last residual {failure.get('last_residual')})")
    if returncode == 2 and "INPUT ERROR" in log_text:
        raise SceneError(f"scene {name}: FreeFEM rejected the input:\n  {freefem_message(log_text)}")
    if returncode < 0:
        raise FreeFemError(f"scene {name}: FreeFEM was killed by {signal.Signals(-returncode).name}"
                           + (" (out of memory?)" if -returncode == signal.SIGKILL else "")
                           + f":\n  {freefem_message(log_text)}")
    if returncode != 0:
        raise FreeFemError(f"scene {name}: FreeFEM failed (exit {returncode}):\n  {freefem_message(log_text)}")
    results_path = staging / "results.json"
    if not results_path.is_file():
        if (staging / "failure.json").is_file():   # the linear solver aborted FreeFEM with exit 0
            failure = parse_json_file(staging / "failure.json")
            raise NewtonError(f"scene {name}: {failure.get('message', 'solver failure')}")
        raise FreeFemError(f"scene {name}: FreeFEM exited normally but wrote no results.json")
    try:
        results = parse_json_file(results_path)
    except (ValueError, OSError) as exc:
        raise FreeFemError(f"scene {name}: results.json is unreadable ({exc})") from None
    if results.get("status") != "converged":
        raise NewtonError(f"scene {name}: run status is {results.get('status')!r}")
    return results


def run_freefem_tool(script, args, output, what):
    """Run a tool of freefem/tools/ (errors, comparisons) that writes one JSON file."""
    output = Path(output)
    output.unlink(missing_ok=True)
    command = [freefem_binary(), "-nw", "-v", "0", str(TOOLS_DIR / script)] + list(args)
    proc = subprocess.run(command, cwd=REPO, env=freefem_env(), capture_output=True, text=True)
    if proc.returncode != 0 or not output.is_file():
        raise FreeFemError(f"{what} failed (exit {proc.returncode}):\n  "
                           f"{freefem_message(proc.stdout + proc.stderr)}")
    return parse_json_file(output)
