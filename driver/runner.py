"""Launch FreeFEM on a scene, each run in its own folder, published atomically.

FreeFEM writes into a hidden staging folder .ID.staging beside the run folder ID
(runs/ID by default, or --out); the staging folder is renamed to ID only when the
run converged and its results.json parses, otherwise to ID.failed (which holds
failure.json and the log, never results.json). See check_output_folder for what
an --out may be.
"""

import datetime
import fcntl
import functools
import hashlib
import json
import os
import re
import resource
import shutil
import signal
import shlex
import subprocess
import threading
import time
from pathlib import Path

from .errors import DriverError, FreeFemError, NewtonError, SceneError
from .paths import FREEFEM_DIR, IN_CHECKOUT, REPO
from .plugins import ensure_plugins
from .resources import available_memory_mb, check_fits
from .surface_input import is_table_name

TOOLS_DIR = FREEFEM_DIR / "tools"     # error measures and cross-checks (run_freefem_tool)
FREEFEM_PLUGIN_DIR = "/usr/lib/freefem++"   # FreeFEM's own plugins (Debian's libfreefem++)


# What the driver sets in FreeFEM's environment: the load path (";" between folders) of
# Debian's plugins, which its binary looks for in the wrong folder, and of the package's
# own (FreeFem++-mpi takes their mpi/ builds), wherever the package is installed: a
# checkout's freefem++.pref says the same, an installed package has none; one BLAS
# thread, as FreeFEM phases are timed with CPU clock() (see freefem/lib/core/results.idp).
FREEFEM_ENV = {"FF_LOADPATH": f"{FREEFEM_PLUGIN_DIR};{FREEFEM_DIR / 'plugins'}", "OMP_NUM_THREADS": "1",
               "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def freefem_env(mpi=False):
    env = dict(os.environ, **FREEFEM_ENV)
    if mpi and os.geteuid() == 0:   # Open MPI's mpirun refuses root without both
        env["OMPI_ALLOW_RUN_AS_ROOT"] = env["OMPI_ALLOW_RUN_AS_ROOT_CONFIRM"] = "1"
    return env


def rerun_text(command):
    """command.txt: the run's FreeFEM command as a shell line that runs it again
    (`sh command.txt`): FreeFEM's working folder, the environment the driver set, the flags."""
    env = " ".join(f"{k}={shlex.quote(v)}" for k, v in FREEFEM_ENV.items())
    return (f"# the FreeFEM run of this folder; sh command.txt runs it again (into this folder)\n"
            f"cd {shlex.quote(str(REPO))} && {env} {shlex.join(command)}\n")


@functools.lru_cache(maxsize=None)
def installed_versions():
    """FreeFEM's and MUMPS's versions: Debian's package versions, else unknown."""
    try:
        status = (Path(os.environ.get("DPKG_ADMINDIR", "/var/lib/dpkg")) / "status").read_text(errors="replace")
    except OSError:
        status = ""
    return {key: package_version(status, package) for key, package in (("freefem", "freefem++"),
                                                                        ("mumps", "libmumps-seq-dev"))}


def package_version(status, package):
    """What `dpkg-query -W -f '${Version}' PACKAGE` prints (None for nothing), read from dpkg's
    status file when it holds one installed instance of the package (the common case: no
    process to start), else from dpkg-query itself."""
    text, key, found = "\n" + status, f"\nPackage: {package}\n", []
    start = text.find(key)
    while start >= 0:         # each paragraph of the package: its lines up to a blank one
        end = text.find("\n\n", start + 1)
        fields = text[start + 1:end if end >= 0 else None].splitlines()
        if "Status: install ok installed" in fields:
            found += [line[len("Version: "):] for line in fields if line.startswith("Version: ")]
        start = text.find(key, start + 1)
    if len(found) == 1:
        return found[0].strip() or None
    query = shutil.which("dpkg-query")
    if query is None:
        return None
    proc = subprocess.run([query, "-W", "-f", "${Version}", package], capture_output=True, text=True)
    return proc.stdout.strip() if proc.returncode == 0 and proc.stdout.strip() else None


def git_commit():
    """The checkout's commit (with -dirty when tracked files changed), or None outside a git checkout."""
    git = shutil.which("git")
    if not IN_CHECKOUT or git is None or not (REPO / ".git").exists():
        return None
    head = subprocess.run([git, "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        return None
    dirty = subprocess.run([git, "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                           capture_output=True, text=True).stdout.strip()
    return head.stdout.strip() + ("-dirty" if dirty else "")


def provenance(command, commit):
    """What made a run (results.json "provenance"); commit: git_commit()'s answer."""
    from . import __version__

    return {"package": "fdcontact", "version": __version__, "git_commit": commit, **installed_versions(),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "host": os.uname().nodename, "command": shlex.join(command)}


class AfterRunPrefetch(threading.Thread):
    """What a run needs once FreeFEM has finished, fetched while it runs on another core:
    the provenance's git queries (subprocesses) and package versions, milliseconds that a
    short run would otherwise wait for. Failures are left for the main thread to meet again
    and report."""

    def __init__(self):
        super().__init__(daemon=True)
        self.commit = None
        self.start()

    def run(self):
        try:
            self.commit = git_commit()
            installed_versions()
        except Exception:
            pass


def freefem_binary():
    path = shutil.which("FreeFem++")
    if path is None:
        raise FreeFemError("FreeFem++ not found on PATH: run 'make setup' "
                           "(Debian packages freefem++ libfreefem++)")
    return path


def freefem_launch(ranks, mpi=False):
    """The command that starts FreeFEM on `ranks` processes of this machine: FreeFem++, or
    Open MPI's mpirun with FreeFem++-mpi for several processes or when the MPI build is needed
    (mpi: solver.compression; --oversubscribe: more processes than cores still run, slowly).
    The plugin built for FreeFem++-mpi is freefem/plugins/mpi/contact_mumps.so."""
    if ranks == 1 and not mpi:
        return [freefem_binary()]
    mpirun, binary = shutil.which("mpirun"), shutil.which("FreeFem++-mpi")
    if mpirun is None or binary is None:
        raise FreeFemError("mpirun or FreeFem++-mpi not found on PATH: run 'make setup' "
                           "(Debian packages openmpi-bin freefem++)")
    if not (FREEFEM_DIR / "plugins" / "mpi" / "contact_mumps.so").is_file():
        raise FreeFemError("freefem/plugins/mpi/contact_mumps.so is missing: run 'make setup'")
    return [mpirun, "-np", str(ranks), "--oversubscribe", binary]


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


def default_runs_dir():
    """runs/ of the checkout; for an installed package, runs/ in the working folder."""
    return REPO / "runs" if IN_CHECKOUT else Path.cwd() / "runs"


def run_id(scene, args):
    digest = hashlib.sha1(" ".join(args).encode()).hexdigest()[:8]
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return f"{scene['scene']['name']}-{stamp}-{digest}"


# Every folder the driver creates holds this file: the driver only ever replaces or
# removes folders that carry it. A failed run's marker says so: failures are never
# replaced or removed.
MARKER = ".fdcontact-run"
MARKER_RUN = "fdcontact run folder\n"
MARKER_FAILED = "fdcontact failed run\n"
LOCK = ".fdcontact-lock"      # held (flock) by the driver and FreeFEM while a run writes its folder
NAME_MAX = 200                # a run folder's name, leaving room for .NAME.staging and NAME.failed-999


def marker_text(folder):
    try:
        return (folder / MARKER).read_text()
    except (OSError, UnicodeDecodeError):
        return None


def is_package_run(folder):
    """A folder this package wrote (it carries the marker file)."""
    return marker_text(folder) is not None


def is_kept_failure(folder):
    return marker_text(folder) == MARKER_FAILED or (folder / "failure.json").exists()


def resolve_out(out_dir):
    """The absolute run folder an --out names. Refused (exit 2): a symbolic link anywhere on the
    path (a run is never published into a link's target), a name too long for its staging and
    failure folders."""
    given = Path(out_dir).expanduser()
    path = given if given.is_absolute() else Path.cwd() / given
    longest = max((len(os.fsencode(part)) for part in path.parts), default=0)
    if longest > NAME_MAX or len(os.fsencode(path)) > 3000:
        raise SceneError(f"--out {str(out_dir)[:60]}...: a folder name has {longest} bytes; at most {NAME_MAX}")
    prefix = Path(path.anchor)
    for part in path.parts[1:]:
        prefix = prefix / part
        if part not in (".", "..") and prefix.is_symlink():
            raise SceneError(f"--out {out_dir}: {prefix} is a symbolic link; name a path without links")
    return Path(os.path.normpath(path))


def check_output_folder(final, replace):
    """Refuse an --out that would lose data: a place that is not a run of this package, a kept
    failure, a previous run without replace=True, the checkout, its parents, the home folder."""
    protected = {Path("/"), Path.home().resolve(), REPO}
    if final in protected or final in REPO.parents or final in Path.home().resolve().parents:
        raise SceneError(f"--out {final}: refusing to write a run into the checkout, its parent folders "
                         f"or the home folder; name a new folder")
    if final.is_symlink() or (final.exists() and not final.is_dir()):
        raise SceneError(f"--out {final}: exists and is not a folder")
    if not final.is_dir():
        return
    if is_package_run(final):
        if is_kept_failure(final):
            raise SceneError(f"--out {final}: holds a failed run, kept for inspection and never replaced; "
                             f"name another folder")
        if not replace:
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


def try_lock(folder):
    """An exclusive lock on folder's lock file (a descriptor), or None while another process
    holds it. The lock dies with the last process holding it: the driver and FreeFEM."""
    try:
        fd = os.open(folder / LOCK, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def retire_stale(staging, final):
    """A staging folder whose writers are all dead becomes FINAL.failed (never removed).
    Returns False when a live process still holds it, or it is not the package's."""
    if not is_package_run(staging):
        return False
    had_lock = (staging / LOCK).exists()
    fd = try_lock(staging)
    if fd is None:
        return False
    try:
        try:
            owner = int((staging / "driver.pid").read_text())
        except (OSError, ValueError):
            owner = None
        if not had_lock and owner is not None and pid_alive(owner):
            return False     # written by a driver without the lock file, still running
        remove_outputs(staging)
        (staging / MARKER).write_text(MARKER_FAILED)
        if not (staging / "failure.json").exists():
            (staging / "failure.json").write_text(json.dumps(
                {"status": "abandoned", "message": "the driver writing this run stopped before it ended"}) + "\n")
        staging.rename(failed_folder(final))
        return True
    finally:
        os.close(fd)


def retire_stale_siblings(parent):
    """Staging folders left in parent by runs whose processes all died (a killed driver, a
    killed Dask worker) become NAME.failed."""
    try:
        names = [entry.name for entry in os.scandir(parent)
                 if entry.name.startswith(".") and entry.name.endswith(".staging") and entry.is_dir()]
    except OSError:
        return
    for name in names:
        staging = Path(parent) / name
        try:
            retire_stale(staging, staging.with_name(name[1:-len(".staging")]))
        except (OSError, SceneError):
            pass     # another run retired it first, or it is not ours: leave it


def claim_staging(staging, final):
    """Create the staging folder, locked, atomically: one writer per output folder. Returns the
    lock's descriptor (FreeFEM inherits it, so the lock lives as long as either process)."""
    staging.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(2):
        claim = staging.parent / f".{final.name[:40]}.claim-{os.getpid()}-{os.urandom(4).hex()}"
        claim.mkdir()
        fd = try_lock(claim)
        (claim / MARKER).write_text(MARKER_RUN)
        (claim / "driver.pid").write_text(f"{os.getpid()}\n")
        os.write(fd, f"{os.getpid()}\n".encode())
        try:
            os.rename(claim, staging)       # fails when staging exists and holds anything
            return fd
        except OSError:
            os.close(fd)
            shutil.rmtree(claim, ignore_errors=True)
        if not retire_stale(staging, final):
            try:
                owner = int((staging / "driver.pid").read_text())
            except (OSError, ValueError):
                owner = None
            raise SceneError(f"--out {final}: another run is writing to it"
                             + (f" (driver pid {owner})" if owner else f" ({staging} exists)"))
    raise SceneError(f"--out {final}: could not claim {staging}")


def failed_folder(final):
    """Where a failed run's log goes: FINAL.failed, or FINAL.failed-2, -3, ... beside
    earlier failures (a run deletes nothing it did not create)."""
    for k in range(1, 1000):
        failed = final.with_name(final.name + (".failed" if k == 1 else f".failed-{k}"))
        if not failed.exists() and not failed.is_symlink():
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
        if is_package_run(old) and not is_kept_failure(old):
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
    """Run FreeFEM for a validated scene (driver.scene.CheckedScene). Returns (results dict,
    run folder, wall seconds).

    FreeFEM writes into a hidden staging folder beside the run folder, claimed
    exclusively and locked while the driver or FreeFEM lives; the staging folder becomes
    the run folder only when the run converged and its results.json parses, otherwise
    FINAL.failed (its inputs, log and failure.json, no result file). The run folder itself
    is left as it was. FreeFEM runs within the scene's limits (time, memory) and dies
    with the driver.
    """
    runs_dir = Path(runs_dir or default_runs_dir()).resolve()
    script = Path(script) if script else FREEFEM_DIR / f"{scene['scene']['script']}.edp"
    if not script.is_file():
        raise SceneError(f"{scene.source}: FreeFEM script not found: {script}")
    ensure_plugins()
    solver = scene.get("solver", {})
    ranks = solver.get("ranks", 1)
    launch_freefem = freefem_launch(ranks, mpi=solver.get("compression", 0) > 0)
    under_mpirun = len(launch_freefem) > 1
    probe_args = module.freefem_args(scene)
    if out_dir:
        final = resolve_out(out_dir)
    else:
        base = runs_dir / run_id(scene, probe_args)
        final, k = base, 1
        while final.exists() or final.with_name(f".{final.name}.staging").exists():
            k += 1
            final = base.with_name(f"{base.name}-{k}")
    check_output_folder(final, replace)
    check_fits(scene, scene.source)
    limits = run_limits(scene)
    retire_stale_siblings(final.parent)
    staging = final.with_name(f".{final.name}.staging")   # same filesystem: rename is atomic
    lock = claim_staging(staging, final)
    proc = None
    try:
        (staging / "scene.json").write_text(json.dumps(scene.to_dict(), indent=2, default=str))
        mesh_file = module.prepare_mesh(scene, staging, run_command)
        args = module.freefem_args(scene, mesh_file=mesh_file)
        entry = write_scene_module(scene, module, script, staging)
        # -Dmacro flags must follow the script name; everything else is -key value.
        command = launch_freefem + ["-nw", "-v", "0", str(entry)] + args + ["-outdir", str(staging)]
        # FreeFEM's output is block-buffered on a pipe: line-buffer it for progress.
        stdbuf = shutil.which("stdbuf")
        launch = [stdbuf, "-oL", "-eL"] + command if stdbuf else command
        (staging / "command.txt").write_text(rerun_text(command))
        prefetch = AfterRunPrefetch()
        start = time.perf_counter()
        with open(staging / "freefem.log", "w") as log:
            proc = subprocess.Popen(launch, cwd=REPO, env=freefem_env(under_mpirun), stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True, errors="replace", pass_fds=(lock,),
                                    preexec_fn=dies_with_parent(signal.SIGTERM if under_mpirun else signal.SIGKILL))
            guard = Guard(proc, limits, tree=under_mpirun)
            for line in proc.stdout:
                log.write(line)
                log.flush()   # the log of a running job can be followed (tail -f)
                if echo is not None:
                    echo(line.rstrip("\n"))
            proc.wait()
            guard.stop()
        wall = time.perf_counter() - start
        guard.check(scene["scene"]["name"], proc.returncode)
        results = check_outcome(proc.returncode, staging, scene["scene"]["name"], ranks)
        prefetch.join()
        from .paraview import paraview_files
        paraview_files(staging, results)
        results["wall_s"] = wall
        results["peak_rss_mb"] = guard.peak_mb
        published = [arg.replace(str(staging), str(final)) for arg in command]   # the run.edp, -outdir
        results["provenance"] = provenance(published, prefetch.commit)
        if scene["scene"].get("units"):
            results["units"] = scene["scene"]["units"]
        (staging / "results.json").write_text(json.dumps(results, indent=1))
        (staging / "command.txt").write_text(rerun_text(published))
        (staging / "driver.pid").unlink()
        publish(staging, final)
        (final / LOCK).unlink()
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
    finally:
        os.close(lock)


def dies_with_parent(signum):
    """What the child runs before exec: the kernel sends it signum when the driver dies (even by
    SIGKILL). FreeFEM gets SIGKILL; mpirun SIGTERM, so that it stops the FreeFEM processes it
    started (SIGKILL would leave them running). libc is loaded here, in the driver."""
    import ctypes

    prctl = ctypes.CDLL(None, use_errno=True).prctl

    def preexec():
        prctl(PR_SET_PDEATHSIG, signum)
        if os.getppid() == 1:      # the driver died before the line above ran
            os._exit(1)
    return preexec


PR_SET_PDEATHSIG = 1


def run_limits(scene):
    """(seconds, MiB) a FreeFEM run may take: limits.time_s and limits.memory_mb (default 95 %
    of the memory available now), and the process's own address-space limit (ulimit -v)."""
    table = scene.get("limits") or {}
    memory = table.get("memory_mb") or 0.95 * available_memory_mb()
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    ulimit = soft / 2 ** 20 if soft not in (resource.RLIM_INFINITY, -1) else None
    return {"time_s": table.get("time_s", 7200.0), "memory_mb": memory, "ulimit_mb": ulimit,
            "explicit_memory": table.get("memory_mb") is not None}


class Guard:
    """Watches a FreeFEM process: its peak resident memory (VmHWM), and stops it (SIGKILL)
    beyond the time or memory limit; check() turns such a stop into one SceneError.
    tree: the process is mpirun, and the run is every process below it (found in /proc
    at each look); otherwise the process alone is read."""

    def __init__(self, proc, limits, tree=False):
        self.proc, self.limits, self.tree = proc, limits, tree
        self.peak_kb = 0
        self.reason = None
        self.start = time.monotonic()
        self.done = threading.Event()
        self.thread = threading.Thread(target=self.watch, daemon=True)
        self.thread.start()

    @property
    def peak_mb(self):
        return self.peak_kb / 1024.0

    def watch(self):
        peaks = {}   # pid -> VmHWM (kB) of FreeFEM and, under mpirun, every process below it
        while not self.done.wait(0.05):
            pids = process_tree(self.proc.pid) if self.tree else [self.proc.pid]
            if self.proc.pid not in pids:
                return
            for pid in pids:
                try:
                    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                        if line.startswith("VmHWM:"):
                            peaks[pid] = max(peaks.get(pid, 0), int(line.split()[1]))
                except (OSError, ValueError):
                    continue
            # mpirun's own memory aside: the processes it starts are the run
            self.peak_kb = sum(kb for pid, kb in peaks.items() if pid != self.proc.pid or len(pids) == 1)
            if self.peak_mb > self.limits["memory_mb"]:
                self.reason = "memory"
            elif time.monotonic() - self.start > self.limits["time_s"]:
                self.reason = "time"
            if self.reason:
                for pid in reversed(pids):
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except OSError:
                        pass
                return

    def stop(self):
        self.done.set()
        self.thread.join(timeout=1)

    def check(self, name, returncode):
        lim = self.limits
        if self.reason == "time":
            raise SceneError(f"scene {name}: FreeFEM ran longer than limits.time_s = {lim['time_s']:g} s and "
                             f"was stopped (raise limits.time_s in the scene's [limits] table)")
        if self.reason == "memory":
            which = ("limits.memory_mb" if lim["explicit_memory"]
                     else "the memory available (95 %, the default of limits.memory_mb)")
            raise SceneError(f"scene {name}: FreeFEM used more than {lim['memory_mb']:.0f} MiB ({which}) and "
                             f"was stopped: coarsen the mesh, lower adapt.max_dofs or raise limits.memory_mb")
        if returncode != 0 and lim["ulimit_mb"] is not None and returncode in MEMORY_DEATHS \
                and self.peak_mb > 0.5 * lim["ulimit_mb"]:
            raise SceneError(f"scene {name}: FreeFEM died ({exit_name(returncode)}) after using "
                             f"{self.peak_mb:.0f} MiB under this process's memory limit (ulimit -v "
                             f"{lim['ulimit_mb']:.0f} MiB): out of memory; coarsen the mesh or raise the limit")


def process_tree(pid):
    """pid and its descendants (from /proc), parents first; [] when pid is gone."""
    children = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat[stat.rindex(")") + 2:].split()[1])
        children.setdefault(ppid, []).append(int(entry.name))
    if not Path(f"/proc/{pid}").exists():
        return []
    tree, todo = [], [pid]
    while todo:
        p = todo.pop(0)
        tree.append(p)
        todo += sorted(children.get(p, []))
    return tree


# How a process ends when an allocation fails: a segmentation fault, an abort (std::bad_alloc),
# FreeFEM's own exit 1 after "Out of memory".
MEMORY_DEATHS = (-signal.SIGSEGV, -signal.SIGABRT, -signal.SIGBUS, 134, 139, 1)


def exit_name(returncode):
    return f"killed by {signal.Signals(-returncode).name}" if returncode < 0 else f"exit {returncode}"


def write_scene_module(scene, module, script, staging):
    """The script FreeFEM runs: for a scene with a scene module (docs/scene-modules.md),
    run.edp in the run folder, which includes scene.idp (beside it, with the files it reads:
    the surface shapes' tables) and then the solver (from the repository root, FreeFEM's
    working folder); else the solver itself."""
    make = getattr(module, "scene_module", None)
    if make is None:
        return script
    (staging / "scene.idp").write_text(make(scene))
    for name, text in getattr(module, "scene_files", lambda _: {})(scene).items():
        (staging / name).write_text(text)
    script = script.resolve()
    name = script.relative_to(REPO).as_posix() if script.is_relative_to(REPO) else str(script)
    if '"' in name or "\n" in name:
        raise SceneError(f"{script}: a script path for FreeFEM's include must not hold quotes or line breaks")
    (staging / "run.edp").write_text(f'include "scene.idp"   // the scene (written by the driver)\n'
                                     f'include "{name}"\n')
    return staging / "run.edp"


# What a failed run keeps: its inputs, its log and why it failed. Whatever else FreeFEM wrote
# (fields, tables, a truncated file after a signal) is removed: nothing that looks like a result.
# The surface shapes' tables (surface-*.txt) are inputs: kept.
KEPT_ON_FAILURE = {MARKER, "scene.json", "scene.idp", "run.edp", "command.txt", "freefem.log",
                   "failure.json", "mesh.msh"}


def remove_outputs(staging):
    for entry in list(os.scandir(staging)):
        if entry.name in KEPT_ON_FAILURE or is_table_name(entry.name):
            continue
        if entry.is_dir(follow_symlinks=False):
            shutil.rmtree(entry.path, ignore_errors=True)
        else:
            os.unlink(entry.path)


def keep_failure(staging, final, error, reason):
    """Turn the staging folder into FINAL.failed (never with a results.json); name it in the error."""
    try:
        remove_outputs(staging)
        (staging / MARKER).write_text(MARKER_FAILED)
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


# mpirun's report of a process that died: "... process rank 1 with PID 42 on node vm exited on
# signal 9 (Killed)."
RANK_DIED = re.compile(r"process rank (\d+) with PID \d+ on node (\S+) exited on signal (\d+)(?: \(([^)]*)\))?")


def check_outcome(returncode, staging, name, ranks=1):
    """Map FreeFEM's exit and files to a result dict or a DriverError."""
    log_text = (staging / "freefem.log").read_text(errors="replace")
    died = RANK_DIED.search(log_text)
    if died and returncode != 0:
        rank, node, signum, what = died.groups()
        raise FreeFemError(f"scene {name}: MPI rank {rank} of {ranks} (node {node}) died on signal {signum}"
                           + (f" ({what})" if what else "")
                           + (", out of memory?" if int(signum) == signal.SIGKILL else "")
                           + ": mpirun stopped the whole run")
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
