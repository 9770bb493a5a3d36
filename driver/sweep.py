"""Parameter sweeps on Dask distributed: expansion, hashing, submission, row store, progress.

A sweep file (TOML) names a base scene and a grid of overrides; every point is one
FreeFEM run (run_point) executed as one Dask task. By default the
tasks run on a distributed.LocalCluster of one single-threaded worker process per
core; --scheduler tcp://HOST:PORT sends them to an existing Dask cluster.

Each point is keyed by a hash of what determines its result: the base scene file's
content, the full set of overrides, the task and the solver's code (freefem/ and the
driver modules that shape a run). A finished point is one small JSON file,
SWEEP_DIR/rows/HASH.json, written atomically (temporary file + os.replace) as soon
as its result arrives; the combined table is rewritten the same way. Running the
sweep again skips every hash already stored, so an interrupted sweep resumes.

Failures: a FreeFEM failure (exit 2/3/4) is a row with its status and message, not
a retry. A worker process that dies while running a point gets the point retried by
the scheduler (distributed.scheduler.allowed-failures, --max-retries on our own
LocalCluster); a point that keeps killing its worker is a KilledWorker row with
Dask's message. KilledWorker and TaskError rows (infrastructure, not results) are
run again on the next resume; FreeFEM failures are kept.

Ctrl-C (SIGINT): the first one stops submitting and waits for the running points
(their rows are stored), the second one aborts them.
"""

import contextlib
import fcntl
import functools
import hashlib
import importlib.util
import itertools
import json
import math
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from .errors import DriverError, SceneError
from .progress import bar as progress_bar
from .paths import PACKAGE, REPO
from .scene import toml_literal

RESULTS_DIR = REPO / "results"
SWEEPS_DIR = REPO / "runs" / "sweeps"
RETRY_ON_RESUME = {"KilledWorker", "TaskError"}     # infrastructure failures, not results
DEFAULT_MAX_RETRIES = 2        # a point may take its worker down this many times, then KilledWorker
# Sources whose change changes a run's result or its row (this module's run_point and
# scene_task): their digest is part of every key.
CODE_MODULES = ("runner", "scene", "schema", "header", "materials", "fd2d", "fd3d", "foundation", "paraview",
                "plugins", "sweep")

SWEEP_KEYS = {"name", "scene", "set", "description"}
DEBUG_KEYS = {"sleep_s", "crash_points"}
TOP_KEYS = {"sweep", "grid", "zip", "debug"}

MAX_POINTS = 10_000           # points of one sweep file, counted before the grid is built

# Defaults the `study` command sets for studies that run their points here.
SETTINGS = {"workers": None, "scheduler": None}


# ---------------------------------------------------------------------------
# Points and keys


@dataclass
class Point:
    """One task: fn(*args) on a worker returns a row (dict); labels identify it in tables."""

    labels: dict
    fn: str                      # "module:function", importable on the workers
    args: tuple
    key: dict                    # JSON-able: everything the result depends on
    index: int = 0
    debug: dict = field(default_factory=dict)   # test hooks (sleep_s, crash), not in the key

    @property
    def hash(self):
        text = json.dumps(self.key, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def file_digest(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@functools.lru_cache(maxsize=None)
def code_digest(extra=()):
    """Digest of the FreeFEM sources, the plugins' sources, the driver modules that
    shape a run and `extra` (full module names: a study's task, task_point) (read once
    per process: the code does not change while a sweep is being set up)."""
    digest = hashlib.sha256()
    files = [(path, path.relative_to(REPO)) for pattern in ("*.edp", "*.idp", "*.cpp", "*.hpp")
             for path in sorted((REPO / "freefem").rglob(pattern))]
    files += [(PACKAGE / f"{module}.py", f"{PACKAGE.name}/{module}.py") for module in CODE_MODULES]
    files += [(module_file(module), module) for module in extra]
    for path, name in files:
        if path.is_file():
            digest.update(str(name).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def module_file(module):
    """The source file of an importable module, by its full dotted name (e.g. a lab study's,
    which sits beside the package in the checkout)."""
    return Path(importlib.util.find_spec(module).origin)


def canonical_overrides(overrides):
    """{dotted key: value} of a list of KEY=VALUE overrides (later ones win)."""
    from .scene import parse_override

    out = {}
    for text in overrides:
        keys, value = parse_override(text)
        out[".".join(keys)] = value
    return dict(sorted(out.items()))


def portable(path):
    """A path as a worker finds it: repository-relative when inside the repository
    (a worker resolves it in its own clone), absolute otherwise (shared filesystem)."""
    path = Path(path).resolve()
    try:
        return {"repo": str(path.relative_to(REPO))}
    except ValueError:
        return {"abs": str(path)}


def resolve(ref):
    return REPO / ref["repo"] if "repo" in ref else Path(ref["abs"])


def scene_point(scene, overrides, runs_dir, labels, index=0, debug=None):
    """A point that runs `scene` with `overrides` (the `python -m driver run` task)."""
    scene = Path(scene)
    sha = file_digest(scene)
    return Point(labels=labels, fn=f"{__name__}:scene_task",
                 args=(dict(portable(scene), sha256=sha), list(overrides), portable(runs_dir)),
                 key={"task": "scene", "scene_sha256": sha, "overrides": canonical_overrides(overrides),
                      "code": code_digest()},
                 index=index, debug=debug or {})


def task_point(fn, args, labels, scene, overrides, extra=None, index=0):
    """A point that runs any importable fn(*args) (the studies' run-and-compare tasks);
    the key covers the scene file, the overrides, the labels, `extra` and the code."""
    module = fn.split(":")[0]
    key = {"task": fn, "scene_sha256": file_digest(scene), "overrides": canonical_overrides(overrides),
           "labels": labels, "extra": extra or {},
           "code": code_digest(extra=(module,))}
    return Point(labels=labels, fn=fn, args=tuple(args), key=key, index=index)


# ---------------------------------------------------------------------------
# Sweep files


@dataclass
class Sweep:
    name: str
    source: Path
    scene: Path
    fixed: list
    params: list                 # one {dotted key: value} per point, in order
    debug: dict


def flatten_params(table, source, section, prefix=""):
    """{'method': {'theta': [..]}} or {'method.theta': [..]} -> {'method.theta': [..]}; a key
    given twice (both ways) or a value listed twice (1 and 1.0 are one value) is refused."""
    out = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            inner = flatten_params(value, source, section, prefix=name + ".")
        elif isinstance(value, list):
            if not value:
                raise SceneError(f"{source}: [{section}] '{name}': empty list (nothing to sweep)")
            if section == "grid":
                refuse_repeats([(v,) for v in value], f"{source}: [grid] '{name}'")
            inner = {name: value}
        else:
            raise SceneError(f"{source}: [{section}] '{name}': expected a list of values, "
                             f"got {str(value)[:80]}")
        for name in inner:
            if name in out:
                raise SceneError(f"{source}: [{section}] '{name}' is given twice (as a dotted and a "
                                 f"quoted key, or in two tables)")
        out.update(inner)
    return out


def refuse_repeats(rows, where):
    """Refuse a value (a zip's tuple of values) listed twice: the same run twice."""
    seen = {}
    for row in rows:
        same = seen.setdefault(tuple(value_identity(v) for v in row), row)
        if same is not row:
            text = ", ".join(toml_literal(v) for v in row)
            first = ", ".join(toml_literal(v) for v in same)
            raise SceneError(f"{where}: the value {text} is listed twice (as {first} and {text})")


def value_identity(value):
    """What makes two swept values the same run: numbers by value (1 == 1.0), the rest as JSON."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return ("number", float(value))
    return ("json", json.dumps(value, sort_keys=True, default=str))


def load_sweep(path):
    """Read and expand a sweep file; every point is validated as a scene before anything runs."""
    from .header import safe_name
    from .scene import load_scene, parse_toml, read_text_file

    path = Path(path)
    source = str(path)
    data = parse_toml(read_text_file(path, "sweep file"), source)
    unknown = set(data) - TOP_KEYS
    if unknown:
        raise SceneError(f"{source}: unknown section or key {sorted(unknown)[0]!r} "
                         f"(known: {', '.join(sorted(TOP_KEYS))})")
    head = data.get("sweep")
    if not isinstance(head, dict):
        raise SceneError(f"{source}: missing [sweep] table (with scene = \"BASE.toml\")")
    unknown = set(head) - SWEEP_KEYS
    if unknown:
        raise SceneError(f"{source}: unknown key 'sweep.{sorted(unknown)[0]}' "
                         f"(known: {', '.join(sorted(SWEEP_KEYS))})")
    if not isinstance(head.get("scene"), str):
        raise SceneError(f"{source}: key 'sweep.scene': the base scene file (a string) is required")
    scene = (path.parent / head["scene"]).resolve()
    if not scene.is_file():
        raise SceneError(f"{source}: key 'sweep.scene': base scene {head['scene']!r} not found ({scene})")
    name = head.get("name", path.stem)
    if not isinstance(name, str) or safe_name(name):
        raise SceneError(f"{source}: key 'sweep.name': {str(name)[:60]!r} is not a plain name (1-100 letters, "
                         f"digits, - _ ., not starting with . or -)")
    fixed = head.get("set", [])
    if not isinstance(fixed, list) or not all(isinstance(s, str) for s in fixed):
        raise SceneError(f"{source}: key 'sweep.set': expected a list of \"KEY=VALUE\" strings")
    debug = data.get("debug", {})
    if not isinstance(debug, dict) or set(debug) - DEBUG_KEYS:
        raise SceneError(f"{source}: [debug]: unknown key (known: {', '.join(sorted(DEBUG_KEYS))})")

    grid = flatten_params(data.get("grid", {}), source, "grid")
    zips = data.get("zip", [])
    zips = [zips] if isinstance(zips, dict) else zips
    if not isinstance(zips, list) or not all(isinstance(z, dict) for z in zips):
        raise SceneError(f"{source}: [zip]: expected a table (or [[zip]] tables) of lists")
    factors = [[{k: v} for v in values] for k, values in grid.items()]
    seen = set(grid)
    for i, group in enumerate(zips):
        group = flatten_params(group, source, "zip")
        lengths = {k: len(v) for k, v in group.items()}
        if len(set(lengths.values())) > 1:
            detail = ", ".join(f"{k}: {n}" for k, n in lengths.items())
            raise SceneError(f"{source}: [zip] lists of unequal length ({detail})")
        if seen & set(group):
            raise SceneError(f"{source}: [zip] '{sorted(seen & set(group))[0]}' is swept twice")
        seen |= set(group)
        if group:
            refuse_repeats(list(zip(*group.values())), f"{source}: [zip] {', '.join(group)}")
            factors.append([dict(zip(group, values)) for values in zip(*group.values())])
    if not factors:
        raise SceneError(f"{source}: empty grid: give [grid] and/or [zip] lists of values to sweep")
    count = math.prod(len(f) for f in factors)
    if count > MAX_POINTS:
        raise SceneError(f"{source}: the grid has {count:,} points; at most {MAX_POINTS:,} (split the sweep)")
    params = [dict(kv for part in combo for kv in part.items()) for combo in itertools.product(*factors)]

    sweep = Sweep(name=name, source=path, scene=scene, fixed=list(fixed), params=params, debug=debug)
    hashes = {}
    for i, point in enumerate(points_of(sweep, SWEEPS_DIR / name)):
        try:
            load_scene(scene, point.args[1])
        except SceneError as exc:
            raise SceneError(f"{source}: point {i} ({describe(point.labels)}): {exc}") from None
        if point.hash in hashes:
            raise SceneError(f"{source}: points {hashes[point.hash]} and {i} are the same run")
        hashes[point.hash] = i
    return sweep


def describe(params):
    return " ".join(f"{k}={toml_literal(v)}" for k, v in params.items())


def points_of(sweep, sweep_dir):
    crash = set(sweep.debug.get("crash_points", []))
    return [scene_point(sweep.scene, sweep.fixed + [f"{k}={toml_literal(v)}" for k, v in params.items()],
                        Path(sweep_dir) / "runs", dict(params), index=i,
                        debug=dict(sleep_s=sweep.debug.get("sleep_s", 0), crash=i in crash))
            for i, params in enumerate(sweep.params)]


# ---------------------------------------------------------------------------
# Tasks (run on the workers)


def run_point(case, overrides, runs_dir=None):
    """Run one scene with overrides; returns (row dict, results or None, run folder or None):
    a run that fails (exit 3, 4) is a row with its status and message, a bad scene raises."""
    from .runner import run_scene
    from .scene import load_scene

    scene, module = load_scene(case, overrides)
    row = {"case": str(case), "overrides": " ".join(overrides)}
    try:
        results, folder, wall = run_scene(scene, module, runs_dir=runs_dir)
    except SceneError:
        raise
    except DriverError as exc:
        row.update(status=type(exc).__name__, message=str(exc).splitlines()[0])
        return row, None, None
    row.update(status="converged", message="", wall_s=wall,
               newton_iterations=results["newton"]["iterations"], dofs=results["dofs"])
    return row, results, folder


def scene_task(scene_ref, overrides, runs_ref):
    """Run one scene with overrides; a row of the run's scalar results."""
    scene = resolve(scene_ref)
    if not scene.is_file() or file_digest(scene) != scene_ref["sha256"]:
        raise RuntimeError(f"{socket.gethostname()}: the worker's {scene} is missing or differs "
                           f"from the client's (update its clone)")
    row, results, folder = run_point(scene, overrides, runs_dir=resolve(runs_ref))
    out = {"status": row["status"], "message": row["message"]}
    if results is not None:
        out.update(wall_s=row["wall_s"], newton_iterations=row["newton_iterations"])
        out.update(flatten_results(results))
        out["folder"] = str(folder)
    return out


SKIP_RESULTS = {"timings_cpu_s", "steps", "adapt", "outputs", "status", "scene", "script", "wall_s", "provenance"}


def flatten_results(results, prefix="", depth=0):
    """Scalars of results.json (and short numeric vectors) as dotted columns."""
    out = {}
    for key, value in results.items():
        if depth == 0 and key in SKIP_RESULTS:
            continue
        name = f"{prefix}{key}"
        if isinstance(value, dict) and depth < 2:
            out.update(flatten_results(value, name + ".", depth + 1))
        elif isinstance(value, (int, float, str, bool)):
            out[name] = value
        elif (isinstance(value, list) and 0 < len(value) <= 4 and not prefix.startswith("newton.")
              and all(isinstance(v, (int, float)) for v in value)):      # not Newton histories
            out.update({f"{name}.{i}": v for i, v in enumerate(value)})
    return out


def execute(fn, args, point_hash, log_ref, debug):
    """The Dask task: log the attempt, run fn(*args), turn a driver error into a row."""
    started = time.time()
    log = resolve(log_ref)
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") as f:           # one short O_APPEND write per attempt
        f.write(f"{point_hash} {socket.gethostname()} {os.getpid()} {started:.3f}\n")
    if debug.get("crash"):
        os.kill(os.getpid(), signal.SIGKILL)          # test hook: this point kills its worker
    if debug.get("sleep_s"):
        time.sleep(float(debug["sleep_s"]))           # test hook: a slow point
    module, name = fn.split(":")
    try:
        row = getattr(importlib.import_module(module), name)(*args)
    except DriverError as exc:
        row = {"status": type(exc).__name__, "message": str(exc).splitlines()[0]}
    except Exception as exc:                          # a bug or a broken worker: retried on resume
        row = {"status": "TaskError", "message": f"{type(exc).__name__}: {exc}".splitlines()[0]}
    return {"row": row, "host": socket.gethostname(), "pid": os.getpid(), "started": started,
            "task_s": time.time() - started}


def ignore_sigint_plugin():
    """Workers of our own LocalCluster (and the FreeFEM they start) ignore SIGINT, which a
    terminal's Ctrl-C sends to the whole process group: the client decides what stops."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class IgnoreSigint(WorkerPlugin):
        name = "fdcontact-ignore-sigint"

        def setup(self, worker):
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return IgnoreSigint()


# ---------------------------------------------------------------------------
# Row store (client side)


def write_atomic(path, text):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class RowStore:
    """SWEEP_DIR/rows/HASH.json, one per finished point."""

    def __init__(self, folder):
        self.folder = Path(folder) / "rows"
        self.records = {}
        if self.folder.is_dir():
            for path in self.folder.glob("*.json"):
                try:
                    record = json.loads(path.read_text())
                except (OSError, ValueError, RecursionError):
                    continue                          # unreadable: the point runs again
                if valid_record(record):
                    self.records[path.stem] = record  # anything else (a hand-edited row): runs again

    def done(self, point_hash, rerun_failed=False):
        record = self.records.get(point_hash)
        if record is None:
            return False
        status = record["row"].get("status")
        return status not in RETRY_ON_RESUME and not (rerun_failed and status != "converged")

    def put(self, point, result):
        record = dict(hash=point.hash, index=point.index, labels=point.labels, key=point.key, **result)
        write_atomic(self.folder / f"{point.hash}.json", json.dumps(record, indent=1, default=str))
        self.records[point.hash] = record
        return record


def valid_record(record):
    """A stored row as put() writes it: a table whose row is a table with a string status."""
    return (isinstance(record, dict) and isinstance(record.get("row"), dict)
            and isinstance(record["row"].get("status"), str))


def row_of(point, record):
    return {**point.labels, **record["row"]}


def write_table(path, points, store, extra_columns=True):
    """The combined table (CSV), rewritten atomically; rows in point order."""
    import pandas as pd

    rows = []
    for p in points:
        record = store.records.get(p.hash)
        if record is None:
            continue
        row = {"index": p.index, **row_of(p, record)} if extra_columns else row_of(p, record)
        if extra_columns:
            row.update(hash=p.hash, host=record.get("host"), task_s=record.get("task_s"))
        rows.append(row)
    write_atomic(path, pd.DataFrame(rows).to_csv(index=False))


# ---------------------------------------------------------------------------
# Execution


class Progress:
    """A bar over the sweep's points on a terminal (driver.progress); elsewhere one
    line per change. The final state is always printed as a line."""

    def __init__(self, name, total, skipped, stream=None):
        self.name, self.total, self.skipped = name, total, skipped
        self.stream = stream or sys.stderr
        self.start = time.perf_counter()
        self.bar = progress_bar(total=total, desc=f"sweep {name}", unit="point", initial=skipped) \
            if self.stream is sys.stderr else None
        self.last = None

    def text(self, done, running, failed, note=""):
        return (f"sweep {self.name}: {done}/{self.total} done ({self.skipped} from earlier runs), "
                f"{running} running, {failed} failed, {time.perf_counter() - self.start:.1f} s"
                + (f"  {note}" if note else ""))

    def show(self, done, running, failed, note=""):
        state = (done, running, failed, note)
        if state == self.last:
            return
        self.last = state
        if self.bar is not None:
            self.bar.update(done - self.bar.n)
            self.bar.set_postfix_str(f"{running} running, {failed} failed" + (f"  {note}" if note else ""))
            return
        self.stream.write(self.text(done, running, failed, note) + "\n")
        self.stream.flush()

    def close(self):
        if self.bar is not None:
            self.bar.close()
            if self.last is not None:
                self.stream.write(self.text(*self.last) + "\n")
                self.stream.flush()


def configure(workers=None, scheduler=None):
    """Where studies send their points (set by `python -m driver study --workers/--scheduler`)."""
    SETTINGS.update(workers=workers, scheduler=scheduler)


def start_client(workers, scheduler, max_retries):
    """A Client on an existing scheduler, or on a new LocalCluster (one thread per worker)."""
    import logging

    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise DriverError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    workers = workers or os.cpu_count() or 1
    # The scheduler runs in this process: its retry bound is read when it starts. Worker
    # processes ignore SIGINT from the start (a Ctrl-C during start-up would hit them).
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if in_main_thread() else None
    try:
        with dask.config.set({"distributed.scheduler.allowed-failures": max_retries}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None, host="127.0.0.1", silence_logs=logging.CRITICAL)
            client = Client(cluster)
            client.register_plugin(ignore_sigint_plugin())
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    return client, cluster


def in_main_thread():
    return threading.current_thread() is threading.main_thread()


class Interrupted(DriverError):
    exit_code = 130


def run_points(points, name, workers=None, scheduler=None, sweep_dir=None, table=None,
               max_retries=DEFAULT_MAX_RETRIES, rerun_failed=False, quiet=False):
    """Run the points not yet stored in SWEEP_DIR/rows (default runs/sweeps/NAME) on Dask;
    return one row per point, in order. `table`: the combined CSV, rewritten per row."""
    workers = workers if workers is not None else SETTINGS["workers"]
    scheduler = scheduler if scheduler is not None else SETTINGS["scheduler"]
    sweep_dir = Path(sweep_dir) if sweep_dir else SWEEPS_DIR / name
    with sweep_lock(sweep_dir, name):
        return run_locked(points, name, workers, scheduler, sweep_dir, table, max_retries, rerun_failed, quiet)


@contextlib.contextmanager
def sweep_lock(sweep_dir, name):
    """One sweep process per sweep folder (a second one would run every point again); the
    lock dies with its process. Staging folders left by killed points become NAME.failed."""
    from .runner import retire_stale_siblings

    sweep_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(sweep_dir / ".sweep-lock", os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            owner = os.pread(fd, 32, 0).decode(errors="replace").strip()
            raise SceneError(f"sweep {name}: already running in {sweep_dir}"
                             + (f" (pid {owner})" if owner else "") + "; wait for it or use another --runs")
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        retire_stale_siblings(sweep_dir / "runs")
        yield
    finally:
        os.close(fd)


def run_locked(points, name, workers, scheduler, sweep_dir, table, max_retries, rerun_failed, quiet):
    store = RowStore(sweep_dir)
    todo = [p for p in points if not store.done(p.hash, rerun_failed)]
    progress = Progress(name, len(points), len(points) - len(todo), stream=open(os.devnull, "w")
                        if quiet else sys.stderr)
    failed = sum(1 for p in points if p.hash in store.records and store.done(p.hash, rerun_failed)
                 and store.records[p.hash]["row"].get("status") != "converged")
    done = len(points) - len(todo)
    if table is not None and not todo:
        write_table(table, points, store)
    if todo:
        done, failed = submit_all(todo, points, store, progress, done, failed, workers, scheduler,
                                  sweep_dir, table, max_retries)
    progress.show(done, 0, failed)
    progress.close()
    return [row_of(p, store.records[p.hash]) for p in points]


def submit_all(todo, points, store, progress, done, failed, workers, scheduler, sweep_dir, table,
               max_retries):
    from distributed import wait
    from distributed.core import CommClosedError

    log_ref = portable(sweep_dir / "attempts.log")
    state = {"stop": 0}

    def on_sigint(signum, frame):
        state["stop"] += 1
        if state["stop"] > 1:
            raise KeyboardInterrupt

    client, cluster = start_client(workers, scheduler, max_retries)
    previous = signal.signal(signal.SIGINT, on_sigint) if in_main_thread() else None
    queue = list(todo)
    running = {}
    dropped = 0
    try:
        progress.show(done, 0, failed)
        while queue or running:
            if state["stop"] and queue:
                progress.show(done, len(running), failed,
                              note=f"interrupted: waiting for the {len(running)} running points "
                                   f"(Ctrl-C again to abort)")
                dropped, queue = len(queue), []
            capacity = max(1, sum(client.nthreads().values()))
            while queue and len(running) < capacity:
                p = queue.pop(0)
                future = client.submit(execute, p.fn, p.args, p.hash, log_ref, p.debug,
                                       key=f"sweep-{p.hash}-{time.time_ns()}", pure=False, retries=0)
                running[future] = p
            if not running:
                break
            try:
                finished, _ = wait(list(running), timeout=0.5, return_when="FIRST_COMPLETED")
            except TimeoutError:           # nothing finished within 0.5 s: refresh the progress line
                finished = []
            for future in finished:
                p = running.pop(future)
                result = collect(future)
                # Release the key now: a worker that dies later would otherwise make the
                # scheduler recompute a result we already hold (the point would run twice).
                future.release()
                store.put(p, result)
                done += 1
                failed += result["row"].get("status") != "converged"
                if table is not None:
                    write_table(table, points, store)
            progress.show(done, len(running), failed)
    except KeyboardInterrupt:
        progress.show(done, len(running), failed, note="aborted")
        raise Interrupted(f"sweep {progress.name}: aborted with {len(running)} points running; "
                          f"{done} of {progress.total} stored, run again to resume") from None
    except (CommClosedError, ConnectionError) as exc:
        raise DriverError(f"sweep {progress.name}: lost the Dask scheduler ({exc}); "
                          f"{done} of {progress.total} stored, run again to resume") from None
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        for future in running:
            future.cancel()
        client.close()
        if cluster is not None:
            cluster.close()
    if dropped:
        raise Interrupted(f"sweep {progress.name}: interrupted; {done} of {progress.total} stored, "
                          f"run again to resume")
    return done, failed


def collect(future):
    """A finished future's result, or a failure row: KilledWorker after the retries."""
    from distributed import KilledWorker

    if future.status == "finished":
        return future.result()
    try:
        future.result()
        raise RuntimeError(f"task {future.key} ended in state {future.status}")
    except KilledWorker as exc:
        message = str(exc).splitlines()[0] if str(exc) else "worker lost"
        return {"row": {"status": "KilledWorker", "message": message}, "host": None}
    except Exception as exc:
        return {"row": {"status": "TaskError", "message": f"{type(exc).__name__}: {exc}".splitlines()[0]},
                "host": None}


# ---------------------------------------------------------------------------
# Command line


def cmd_sweep(args):
    if args.workers is not None and args.scheduler:
        raise SceneError("--workers and --scheduler exclude each other (the cluster's workers are used)")
    if args.workers is not None and args.workers < 1:
        raise SceneError(f"--workers {args.workers}: expected at least 1")
    sweep = load_sweep(args.file)
    sweep_dir = Path(args.runs) if args.runs else SWEEPS_DIR / sweep.name
    results = Path(args.results) if args.results else RESULTS_DIR
    table = results / f"sweep_{sweep.name}.csv"
    points = points_of(sweep, sweep_dir)
    rows = run_points(points, sweep.name, workers=args.workers, scheduler=args.scheduler,
                      sweep_dir=sweep_dir, table=table, max_retries=args.max_retries,
                      rerun_failed=args.rerun_failed)
    bad = [r for r in rows if r.get("status") != "converged"]
    print(f"wrote {table} ({len(rows)} rows, {len(bad)} not converged)")
    for r in bad:
        print(f"  {describe({k: r[k] for k in sweep.params[0]})}: {r['status']}: {r.get('message', '')}")
    return 0


def add_parser(sub):
    p = sub.add_parser("sweep", help="run a parameter sweep (sweep file) on Dask, resumable")
    p.add_argument("file", help="sweep file (TOML), e.g. cases/sweeps/smoke.toml")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes, one FreeFEM run each (default: the number of cores)")
    p.add_argument("--scheduler", help="an existing Dask scheduler, tcp://HOST:PORT, instead of local workers")
    p.add_argument("--results", help="folder of the table sweep_NAME.csv (default results/)")
    p.add_argument("--runs", help="sweep folder: rows/, runs/, attempts.log (default runs/sweeps/NAME)")
    p.add_argument("--max-retries", type=int, default=DEFAULT_MAX_RETRIES,
                   help="times a point may lose its worker before it is a KilledWorker row (local cluster)")
    p.add_argument("--rerun-failed", action="store_true", help="run stored non-converged points again")
    p.set_defaults(func=cmd_sweep)
    b = sub.add_parser("sweep-bench", help="time a sweep with 1 and 2 workers: results/sweep_bench.csv")
    b.add_argument("file", nargs="?", default=str(REPO / "cases" / "sweeps" / "smoke.toml"))
    b.add_argument("--repeats", type=int, default=3)
    b.set_defaults(func=cmd_bench)


# ---------------------------------------------------------------------------
# Benchmark: wall time of the whole command with 1 and 2 workers (timing lives here, not in tests)


def load_1min():
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


def machine_busy_s():
    """CPU seconds the whole machine has spent busy since boot (/proc/stat)."""
    try:
        fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    except (OSError, ValueError, IndexError):
        return float("nan")
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)           # idle + iowait
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def children_cpu_s():
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def cmd_bench(args):
    import pandas as pd

    if args.repeats < 1:
        raise SceneError(f"--repeats {args.repeats}: expected at least 1")
    sweep = load_sweep(args.file)
    rows = []
    for repeat in range(1, args.repeats + 1):
        for workers in ((1, 2) if repeat % 2 else (2, 1)):
            with tempfile.TemporaryDirectory(prefix="sweep-bench-") as tmp:
                load = load_1min()
                busy0, ours0 = machine_busy_s(), children_cpu_s()
                start = time.perf_counter()
                proc = subprocess.run([sys.executable, "-m", "driver", "sweep", str(args.file),
                                       "--workers", str(workers), "--results", tmp, "--runs", f"{tmp}/sweep"],
                                      cwd=REPO, capture_output=True, text=True)
                wall = time.perf_counter() - start
                # Other users' CPU during the run, in cores: the machine's busy time less
                # ours (the sweep, its workers and their FreeFEM runs, all waited for).
                others = max(0.0, (machine_busy_s() - busy0) - (children_cpu_s() - ours0)) / wall
                if proc.returncode != 0:
                    raise DriverError(f"sweep-bench: the sweep failed with --workers {workers}:\n"
                                      f"{proc.stderr.strip()[-2000:]}")
                table = pd.read_csv(Path(tmp) / f"sweep_{sweep.name}.csv")
            rows.append(dict(kind="run", workers=workers, repeat=repeat, wall_s=wall, load_1min=load,
                             other_cores=others, points=len(table),
                             converged=int((table.status == "converged").sum())))
            print(f"repeat {repeat}, --workers {workers}: {wall:.2f} s (load before {load:.2f}, "
                  f"others' CPU during the run {others:.2f} cores)", flush=True)
    runs = pd.DataFrame(rows)
    med = {w: statistics.median(runs[runs.workers == w].wall_s) for w in (1, 2)}
    summary = [dict(kind="median", workers=w, wall_s=med[w], points=len(sweep.params)) for w in (1, 2)]
    summary.append(dict(kind="ratio_2_over_1", workers=2, wall_s=med[2] / med[1]))
    out = pd.concat([runs, pd.DataFrame(summary)], ignore_index=True)
    RESULTS_DIR.mkdir(exist_ok=True)
    write_atomic(RESULTS_DIR / "sweep_bench.csv", out.to_csv(index=False))
    print(f"median wall: --workers 1 {med[1]:.2f} s, --workers 2 {med[2]:.2f} s, "
          f"ratio {med[2] / med[1]:.3f} ({os.cpu_count()} cores); wrote {RESULTS_DIR / 'sweep_bench.csv'}")
    return 0
