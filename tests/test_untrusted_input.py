"""Untrusted input, round 2: gmsh files as data, run folders that never lose data, limits
before work, one line instead of a traceback.

Each test reproduces a reported case and checks the promised outcome (docs/reliability.md):
the exit code, one clear error line, and the files left behind. The security tests fail
when the payload runs (a file PWNED appears).
"""

import fcntl
import json
import os
import resource
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.conftest import BODY_ON_SLAB, REPO, run_cli

RECTANGLE = """\
Point(1) = {-0.2, -0.25, 0};
Point(2) = {0.2, -0.25, 0};
Point(3) = {0.2, 0.1, 0};
Point(4) = {-0.2, 0.1, 0};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
"""

SCENE = BODY_ON_SLAB + """\
[output]
vtu = false
estimators = false
"""

DISK_SHAPE = '{ type = "disk", centre = [0.0, 0.0], radius = 0.25 }'
def payload(folder):
    """gmsh code that creates FOLDER/PWNED when it runs (an absolute path: gmsh may run anywhere)."""
    return f'SystemCall "touch {Path(folder) / "PWNED"}";\n'


def scene(folder, shape=DISK_SHAPE, extra="", name="scene.toml"):
    path = Path(folder) / name
    path.write_text(SCENE.format(nx=20, shape=shape) + textwrap.dedent(extra))
    return path


def gmsh_scene(folder, geo_name="shape.geo"):
    return scene(folder, f'{{ type = "gmsh", file = "{geo_name}", size = 0.05 }}')


def one_error(proc, code, *words):
    """The process exited with `code` and printed one error line holding `words`, no traceback."""
    assert proc.returncode == code, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, proc.stderr
    first = errors[0]
    for word in words:
        assert word in first, first
    return first


def pwned(*folders):
    return any((Path(f) / "PWNED").exists() for f in (*folders, REPO, Path.cwd()))


# ---- gmsh input is data ------------------------------------------------------------------

def test_a_clean_gmsh_rectangle_is_accepted(tmp_path):
    (tmp_path / "shape.geo").write_text(RECTANGLE)
    proc = run_cli("scene-module", str(gmsh_scene(tmp_path)), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "lsSegmentDist2" in proc.stdout


@pytest.mark.parametrize("statement", [
    'MergeWithBoundingBox "payload.geo";', 'Merge "payload.geo";', 'Include "payload.geo";',
    'SystemCall "touch {pwned}";', 'NonBlockingSystemCall "touch {pwned}";', 'OnelabRun("x", "touch {pwned}");',
    'Save "out.msh";', 'Printf("x") > "out.txt";', 'Exit;', 'Plugin(Crack).Run;', 'General.Terminal = 1;',
    'Mesh 2;', 'Delete Model;', 'CreateDir "x";', 'Sleep 100;', 'SetName "x";', 'Abort;',
])
def test_a_geo_statement_outside_the_allow_list_is_refused_and_never_runs(tmp_path, statement):
    (tmp_path / "payload.geo").write_text(payload(tmp_path))
    (tmp_path / "shape.geo").write_text(RECTANGLE + statement.replace("{pwned}", str(tmp_path / "PWNED")) + "\n")
    proc = run_cli("scene-module", str(gmsh_scene(tmp_path)), cwd=tmp_path)
    one_error(proc, 2, "is refused")
    assert not pwned(tmp_path)
    assert not (tmp_path / "out.msh").exists() and not (tmp_path / "out.txt").exists()


def test_gmsh_never_reads_a_sidecar_option_file(tmp_path):
    """gmsh reads NAME.geo.opt beside NAME.geo: the driver meshes a copy in a private folder."""
    (tmp_path / "opt.geo").write_text(RECTANGLE)
    (tmp_path / "opt.geo.opt").write_text(payload(tmp_path))
    proc = run_cli("scene-module", str(gmsh_scene(tmp_path, "opt.geo")), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert not pwned(tmp_path)


@pytest.mark.parametrize("where", ["absolute", "parent", "link"])
def test_a_gmsh_file_outside_the_scene_folder_is_refused(tmp_path, where):
    inner = tmp_path / "scenes"
    inner.mkdir()
    (tmp_path / "outside.geo").write_text(RECTANGLE)
    name = {"absolute": str(tmp_path / "outside.geo"), "parent": "../outside.geo", "link": "link.geo"}[where]
    if where == "link":
        (inner / "link.geo").symlink_to(tmp_path / "outside.geo")
    proc = run_cli("scene-module", str(gmsh_scene(inner, name)), cwd=tmp_path)
    one_error(proc, 2, "body1.shape.file")


def test_the_foundation_geometry_is_read_as_data(tmp_path):
    text = (REPO / "cases" / "square_slip_separation_gmsh.toml").read_text()
    (tmp_path / "geo").mkdir()
    (tmp_path / "geo" / "unit_square.geo").write_text((REPO / "cases/geo/unit_square.geo").read_text() + payload(tmp_path))
    (tmp_path / "scene.toml").write_text(text)
    proc = run_cli("run", str(tmp_path / "scene.toml"), "--out", str(tmp_path / "r"), cwd=tmp_path)
    one_error(proc, 2, "geometry.geo", "is refused")
    assert not pwned(tmp_path) and not (tmp_path / "r").exists()


@pytest.mark.parametrize("content", [b"garbage\n$MeshFormat\nfoo\n", os.urandom(300), b""])
def test_a_garbage_msh_gives_one_line(tmp_path, content):
    (tmp_path / "shape.msh").write_bytes(content)
    proc = run_cli("scene-module", str(gmsh_scene(tmp_path, "shape.msh")), cwd=tmp_path)
    one_error(proc, 2, "shape.msh")
    assert len(proc.stderr.strip().splitlines()) == 1


def test_a_tiny_gmsh_size_is_refused_before_gmsh_starts(tmp_path):
    (tmp_path / "shape.geo").write_text(RECTANGLE)
    path = scene(tmp_path, '{ type = "gmsh", file = "shape.geo", size = 1e-7 }')
    proc = run_cli("scene-module", str(path), cwd=tmp_path)
    one_error(proc, 2, "size", "edges")


@pytest.mark.freefem
def test_plot_reads_only_files_inside_the_run_folder(tmp_path):
    (tmp_path / "outside.csv").write_text("x,y,pressure,weight\n0,0,1,1\n")
    run = tmp_path / "run"
    proc = run_cli("run", str(scene(tmp_path)), "--out", str(run))
    assert proc.returncode == 0, proc.stderr
    results = json.loads((run / "results.json").read_text())
    results["outputs"]["pressure_csv"] = str(tmp_path / "outside.csv")
    (run / "results.json").write_text(json.dumps(results))
    one_error(run_cli("plot", str(run)), 2, "outside the run folder")
    for key in ("contact", "steps"):
        broken = dict(results, outputs={}, **{key: [1, 2]})
        (run / "results.json").write_text(json.dumps(broken))
        one_error(run_cli("plot", str(run)), 2, key)


# ---- run folders: nothing lost ----------------------------------------------------------

def test_a_folder_that_only_looks_like_an_old_run_is_not_removed(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    for name in ("scene.json", "command.txt", "freefem.log", "precious.txt"):
        (out / name).write_text(name)
    proc = run_cli("run", str(scene(tmp_path)), "--out", str(out))
    one_error(proc, 2, "not a run of this package")
    assert sorted(p.name for p in out.iterdir()) == ["command.txt", "freefem.log", "precious.txt", "scene.json"]


@pytest.mark.freefem
def test_a_kept_failure_is_never_replaced(tmp_path):
    path = scene(tmp_path)
    out = tmp_path / "r"
    proc = run_cli("run", str(path), "--out", str(out), "--set", "solver.newton_max=1")
    assert proc.returncode == 3, proc.stderr
    failed = tmp_path / "r.failed"
    before = {p.name: p.read_bytes() for p in failed.iterdir()}
    for extra in ([], ["--replace"]):
        proc = run_cli("run", str(path), "--out", str(failed), *extra)
        one_error(proc, 2, "failed run")
    assert {p.name: p.read_bytes() for p in failed.iterdir()} == before


@pytest.mark.parametrize("kind", ["link", "dangling", "parent"])
def test_a_symlink_on_the_out_path_is_refused(tmp_path, kind):
    target = tmp_path / "target"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target if kind != "dangling" else tmp_path / "nowhere")
    out = link / "run" if kind == "parent" else link
    proc = run_cli("run", str(scene(tmp_path)), "--out", str(out))
    one_error(proc, 2, "symbolic link")
    assert list(target.iterdir()) == [] and not (tmp_path / "nowhere").exists()


def test_an_out_name_too_long_is_bad_input(tmp_path):
    proc = run_cli("run", str(scene(tmp_path)), "--out", str(tmp_path / ("a" * 300)))
    one_error(proc, 2, "300 bytes")


@pytest.mark.freefem
def test_a_killed_driver_leaves_no_freefem_and_its_folder_becomes_a_failure(tmp_path):
    """SIGKILL of the driver: FreeFEM dies with it (no orphan writing into the folder), and
    the next run into the same --out retires the stale staging folder as OUT.failed."""
    out = tmp_path / "r"
    path = scene(tmp_path)
    driver = subprocess.Popen([sys.executable, "-m", "driver", "run", str(path), "--out", str(out),
                               "--set", "mesh.nx=300", "--set", "method.degree=2"],
                              cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    staging = tmp_path / ".r.staging"
    deadline = time.monotonic() + 60
    while not (staging / "freefem.log").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)
    assert freefem_writing(staging), "FreeFEM did not start"
    driver.send_signal(signal.SIGKILL)
    driver.wait()
    deadline = time.monotonic() + 10
    while freefem_writing(staging) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not freefem_writing(staging)
    proc = run_cli("run", str(path), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "r.failed" / "failure.json").read_text())["status"] == "abandoned"
    assert not staging.exists()


def freefem_writing(staging):
    """A live process whose command line names the staging folder."""
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
            state = Path(f"/proc/{pid}/stat").read_text().split()[2]
        except OSError:
            continue
        if str(staging).encode() in cmdline and b"FreeFem" in cmdline and state != "Z":
            return True
    return False


@pytest.mark.freefem
def test_a_failed_run_keeps_no_partial_output(tmp_path):
    """Under a file-size limit FreeFEM dies (SIGXFSZ) in the middle of a VTU: the failure folder
    keeps the inputs and the log, no result file."""
    out = tmp_path / "r"

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))

    proc = subprocess.run([sys.executable, "-m", "driver", "run", str(scene(tmp_path)), "--out", str(out),
                           "--set", "output.vtu=true", "--set", "mesh.nx=40"], cwd=REPO,
                          env=dict(os.environ, PYTHONPATH=str(REPO)), capture_output=True, text=True,
                          preexec_fn=small_files)
    one_error(proc, 4, "SIGXFSZ")
    kept = sorted(p.name for p in (tmp_path / "r.failed").iterdir())
    assert kept == sorted([".fdcontact-run", "command.txt", "failure.json", "freefem.log", "run.edp",
                           "scene.idp", "scene.json"])


# ---- limits before work ------------------------------------------------------------------

@pytest.mark.freefem
@pytest.mark.parametrize("override,words", [
    ("limits.time_s=0.2", ("limits.time_s",)),
    ("limits.memory_mb=20", ("20 MiB", "limits.memory_mb")),
])
def test_freefem_runs_within_the_scene_limits(tmp_path, override, words):
    proc = run_cli("run", str(scene(tmp_path)), "--out", str(tmp_path / "r"), "--set", "mesh.nx=200",
                   "--set", "method.degree=2", "--set", override)
    one_error(proc, 2, *words)
    assert not (tmp_path / "r").exists() and (tmp_path / "r.failed" / "failure.json").is_file()


@pytest.mark.freefem
def test_a_process_memory_limit_is_named_when_freefem_dies_of_it(tmp_path):
    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (700 * 2 ** 20, 700 * 2 ** 20))

    proc = subprocess.run([sys.executable, "-m", "driver", "run", str(scene(tmp_path)), "--out",
                           str(tmp_path / "r"), "--set", "mesh.nx=250", "--set", "method.degree=2"], cwd=REPO,
                          env=dict(os.environ, PYTHONPATH=str(REPO)), capture_output=True, text=True,
                          preexec_fn=limited)
    one_error(proc, 2, "ulimit -v", "out of memory")


def nested_unions(depth):
    shape = DISK_SHAPE
    for _ in range(depth):
        shape = f'{{ type = "union", rotate = 10.0, of = [{shape}] }}'
    return shape


@pytest.mark.parametrize("shape,words", [
    (nested_unions(16), ("characters of FreeFEM code",)),
    (nested_unions(17), ("nested more than 16",)),
    (nested_unions(30), ("nested",)),
    ('{ type = "expression", phi = "min(x, 1' + "0" * 400 + ')" }', ("not a finite",)),
    ('{ type = "expression", phi = "' + "-" * 1970 + 'x" }', ("nested",)),
    ('{ type = "expression", phi = "' + "+".join(["x"] * 999) + '" }', ("nested",)),
    ('{ type = "expression", phi = "x - 1e999" }', ("not a finite",)),
    ('{ type = "polygon", vertices = [[-0.2, -0.25], [0.2, 0.1], [0.2, -0.25], [-0.2, 0.1]] }',
     ("crosses itself",)),
])
def test_shapes_beyond_the_limits_give_one_line(tmp_path, shape, words):
    proc = run_cli("scene-module", str(scene(tmp_path, shape)), cwd=tmp_path)
    one_error(proc, 2, *words)


@pytest.mark.parametrize("extra,key", [
    ("[[probe]]\nname = \"p\"\npoint = [0.0, 0.0]\nbody = 1.0\n", "probe.0.body"),
    ("[[probe]]\nname = \"p\"\npoint = [0.0, nan]\n", "probe.0.point"),
    ("[adapt]\nsteps = 100000\n", "adapt.steps"),
    ("[adapt]\nsteps = 3\ngrowth = 1e300\n", "adapt.growth"),
])
def test_values_that_used_to_raise_give_one_line(tmp_path, extra, key):
    path = scene(tmp_path, extra=extra)
    if "adapt" in extra:
        path.write_text(path.read_text().replace("estimators = false", "estimators = true"))
    proc = run_cli("run", str(path), "--out", str(tmp_path / "r"))
    one_error(proc, 2, key)


@pytest.mark.parametrize("script_scene,nx", [("cases/disk_on_slab.toml", "1" + "0" * 200),
                                             ("cases/ball_on_slab.toml", "1" + "0" * 80)])
def test_a_huge_integer_mesh_size_is_bad_input(tmp_path, script_scene, nx):
    text = (REPO / script_scene).read_text().replace("nx = ", f"nx = {nx} #", 1)
    (tmp_path / "s.toml").write_text(text)
    one_error(run_cli("run", str(tmp_path / "s.toml"), "--out", str(tmp_path / "r")), 2, "mesh.nx")


def test_deeply_nested_toml_is_bad_input(tmp_path):
    path = scene(tmp_path)
    path.write_text(path.read_text() + "deep = " + "[" * 5000 + "]" * 5000 + "\n")
    one_error(run_cli("scene-module", str(path)), 2, "nested")


@pytest.mark.freefem
def test_a_quoted_override_value_keeps_its_spaces_and_equals(tmp_path):
    proc = run_cli("run", str(scene(tmp_path)), "--out", str(tmp_path / "r"),
                   "--set", 'scene.description="load b=5 kN" mesh.nx=12')
    assert proc.returncode == 0, proc.stderr
    saved = json.loads((tmp_path / "r" / "scene.json").read_text())
    assert saved["scene"]["description"] == "load b=5 kN" and saved["mesh"]["nx"] == 12


# ---- sweeps ------------------------------------------------------------------------------

def sweep_file(folder, body, name="sw"):
    scene(folder, name="base.toml")
    path = Path(folder) / f"{name}.toml"
    path.write_text(f'[sweep]\nscene = "base.toml"\n{body}')
    return path


@pytest.mark.parametrize("body,words", [
    ('name = ".."\n[grid]\n"mesh.nx" = [10]\n', ("sweep.name",)),
    ('[grid]\n"method.theta" = [1.0]\nmethod.theta = [0.0]\n', ("given twice",)),
    ('[grid]\n"method.theta" = [1, 1.0]\n', ("listed twice",)),
    ('[grid]\n' + "".join(f'"probe{k}" = [{", ".join(str(v) for v in range(10))}]\n' for k in range(9)),
     ("1,000,000,000 points",)),
])
def test_bad_sweep_files_give_one_line(tmp_path, body, words):
    proc = run_cli("sweep", str(sweep_file(tmp_path, body)), "--runs", str(tmp_path / "runs"),
                   "--results", str(tmp_path))
    one_error(proc, 2, *words)


def test_a_second_sweep_on_the_same_folder_is_refused(tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    fd = os.open(runs / ".sweep-lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    os.write(fd, b"4242\n")
    try:
        proc = run_cli("sweep", str(sweep_file(tmp_path, '[grid]\n"mesh.nx" = [10]\n')), "--runs", str(runs),
                       "--results", str(tmp_path))
    finally:
        os.close(fd)
    one_error(proc, 2, "already running", "4242")


def test_hand_edited_rows_are_run_again_not_a_traceback(tmp_path):
    from driver.sweep import RowStore

    rows = tmp_path / "rows"
    rows.mkdir()
    (rows / "a.json").write_text("{}")
    (rows / "b.json").write_text("[1, 2]")
    (rows / "c.json").write_text(json.dumps({"row": {"status": "converged"}}))
    store = RowStore(tmp_path)
    assert sorted(store.records) == ["c"]
    assert not store.done("a") and not store.done("b") and store.done("c")
