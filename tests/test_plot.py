"""python -m driver plot RUN: the figures of a 2D and a 3D run, the plane-cut and clipping
geometry, and the one-line refusal (exit 2) of folders that are not converged runs."""

import json
import shutil

import matplotlib.image as mpimg
import numpy as np
import pytest

from conftest import REPO, run_cli
from driver.plot import clip_triangles, cut_tetrahedra, parse_plane, RunFolderError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def run_2d(tmp_path_factory):
    return make_run(tmp_path_factory, "cases/disk_on_slab.toml", "mesh.nx=20")


@pytest.fixture(scope="module")
def run_3d(tmp_path_factory):
    return make_run(tmp_path_factory, "cases/ball_on_slab.toml", "mesh.nx=6")


def make_run(factory, case, *overrides):
    out = factory.mktemp("plot") / "run"
    args = ["run", str(REPO / case), "--out", str(out)]
    for item in overrides:
        args += ["--set", item]
    proc = run_cli(*args)
    assert proc.returncode == 0, proc.stderr
    return out


def plot(*args):
    return run_cli("plot", *map(str, args))


def check_png(path, min_width=600, min_height=400):
    assert path.read_bytes()[:8] == PNG_SIGNATURE, path
    image = mpimg.imread(path)
    height, width = image.shape[:2]
    assert width >= min_width and height >= min_height, (path, image.shape)
    assert image[..., :3].std() > 0.05, f"{path} is (nearly) blank"


def written(proc):
    return [line for line in proc.stdout.splitlines() if line]


def assert_plotted(proc, folder, names):
    """The plot command succeeded, printed exactly these files in order, each a PNG."""
    assert proc.returncode == 0, proc.stderr
    assert written(proc) == [str(folder / n) for n in names]
    for name in names:
        check_png(folder / name)


@pytest.mark.freefem
def test_plot_2d(run_2d):
    assert_plotted(plot(run_2d), run_2d, ["plot_deformed.png", "plot_pressure.png", "plot_newton.png"])
    assert not list(run_2d.glob(".plot-*")), "a temporary file was left behind"


@pytest.mark.freefem
def test_plot_3d_default_plane_and_chosen_plane(run_3d):
    # the ball touches the slab at (0, 0, -0.25): the default cut is y = 0
    assert_plotted(plot(run_3d), run_3d, ["plot_cut_y0.png", "plot_pressure.png", "plot_newton.png"])
    proc = plot(run_3d, "--plane", "x=0.05", "--scale", "5")
    assert proc.returncode == 0, proc.stderr
    check_png(run_3d / "plot_cut_x0.05.png")


@pytest.mark.freefem
def test_plot_reads_a_recovered_column_and_a_signed_pressure(run_2d, tmp_path):
    import pandas as pd

    copy = tmp_path / "copy"
    shutil.copytree(run_2d, copy)
    frame = pd.read_csv(copy / "contact_pressure.csv")
    frame["pressure_recovered"] = frame["pressure"]
    frame["pressure"] = -frame["pressure"]            # written <= 0, as the foundation and older runs
    frame.to_csv(copy / "contact_pressure.csv", index=False)
    proc = plot(copy)
    assert proc.returncode == 0, proc.stderr
    check_png(copy / "plot_pressure.png")


def bad_folders(root, run_2d):
    """name -> (folder, expected words of the message)."""
    cases = {}
    cases["missing"] = (root / "nowhere", "no such run folder")
    (root / "a_file").write_text("x")
    cases["file"] = (root / "a_file", "not a folder")
    (root / "empty").mkdir()
    cases["empty"] = (root / "empty", "no results.json")
    failed = root / "run.failed"
    failed.mkdir()
    (failed / "failure.json").write_text(json.dumps({"status": "unbalanced", "message": "load on the pins"}))
    cases["failed"] = (failed, "failed run")
    for name, damage, words in [
        ("bad_json", lambda d: (d / "results.json").write_text("{not json"), "malformed JSON"),
        ("bad_vtu", lambda d: (d / "body1.vtu").write_text("<VTKFile>cut short"), "unreadable VTU"),
        ("no_vtu", lambda d: (d / "body2.vtu").unlink(), "body2.vtu: missing"),
        ("bad_csv", lambda d: (d / "contact_pressure.csv").write_text("x,y\n0,1\n"), "no column pressure"),
        ("no_newton", lambda d: rewrite_results(d, newton={}), "no Newton history"),
    ]:
        folder = root / name
        shutil.copytree(run_2d, folder, ignore=shutil.ignore_patterns("plot_*.png"))
        damage(folder)
        cases[name] = (folder, words)
    return cases


def rewrite_results(folder, **changes):
    results = json.loads((folder / "results.json").read_text())
    results.update(changes)
    (folder / "results.json").write_text(json.dumps(results))


@pytest.mark.freefem
def test_bad_folders_give_one_line_and_exit_2(run_2d, tmp_path):
    for name, (folder, words) in bad_folders(tmp_path, run_2d).items():
        before = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else None
        proc = plot(folder)
        lines = proc.stderr.splitlines()
        assert proc.returncode == 2, (name, proc.returncode, proc.stderr)
        assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], (name, proc.stderr)
        assert proc.stdout == "", name
        after = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else None
        assert after == before, f"{name}: plot wrote into a folder it refused"
    assert not (tmp_path / "nowhere").exists()


@pytest.mark.freefem
def test_bad_planes(run_2d, run_3d):
    for folder, plane, words in [(run_2d, "y=0", "for 3D runs"), (run_3d, "w=1", "expected AXIS=VALUE"),
                                 (run_3d, "y=inf", "finite"), (run_3d, "z=3", "misses both bodies")]:
        proc = plot(folder, "--plane", plane)
        assert proc.returncode == 2, (plane, proc.stderr)
        assert len(proc.stderr.splitlines()) == 1 and words in proc.stderr, (plane, proc.stderr)


def test_clip_triangles_area():
    """{x + y < 1.25} in the square [0, 1]^2 meshed by 8 x 8 x 2 triangles: the clip is exact
    for a linear level set (area 1 - 0.75^2/2)."""
    n = 8
    grid = np.linspace(0, 1, n + 1)
    x, y = np.meshgrid(grid, grid, indexing="ij")
    points = np.column_stack([x.ravel(), y.ravel()])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    phi = points.sum(axis=1) - 1.25
    data, clipped, segments = clip_triangles(tris, np.column_stack([points, phi]), 2)
    p = data[clipped]
    area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                        - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])).sum()
    assert area == pytest.approx(1 - 0.75 ** 2 / 2, rel=1e-12)
    assert np.abs(data[segments.ravel(), 2]).max() < 1e-12            # the outline is on phi = 0
    length = np.linalg.norm(data[segments[:, 0], :2] - data[segments[:, 1], :2], axis=1).sum()
    assert length == pytest.approx(0.75 * np.sqrt(2), rel=1e-12)


def test_cut_tetrahedra_section():
    """The unit cube in 6 tetrahedra cut at z = 0.3 and through its top face (vertices on the
    plane count on its + side: the face comes once, from the tetrahedra below): a unit square."""
    corners = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], dtype=float)
    tets = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])
    values = corners[:, 0] + 2 * corners[:, 1]                         # a linear field rides along
    for level in (0.3, 1.0):
        data, tris = cut_tetrahedra(tets, np.column_stack([corners, values]), 2, level)
        p = data[tris][:, :, :2]
        area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                            - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])).sum()
        assert area == pytest.approx(1.0, rel=1e-12), level
        assert np.allclose(data[:, 2], level)
        assert np.allclose(data[:, 3], data[:, 0] + 2 * data[:, 1])


def test_parse_plane():
    assert parse_plane("y=0") == (1, 0.0)
    assert parse_plane(" X = -0.25 ") == (0, -0.25)
    for text in ("y", "y=", "w=1", "y=nan", "y=1=2"):
        with pytest.raises(RunFolderError):
            parse_plane(text)


def test_the_stress_colour_range_ignores_a_few_cut_cell_peaks():
    """vm_norm ends the colour range at the 99th percentile of the nodal values: one node of
    1000 at 50 times the rest does not set the scale."""
    from driver.plot import VM_PERCENTILE, Piece, vm_norm

    k = np.arange(333)
    xy = np.zeros((999, 2))
    xy[3 * k], xy[3 * k + 1], xy[3 * k + 2] = np.c_[k, 0 * k], np.c_[k + 1, 0 * k], np.c_[k, 0 * k + 1]
    vm = np.linspace(0.0, 1.0, 999)
    vm[17] = 50.0
    piece = Piece("body 1", xy, np.arange(999).reshape(333, 3), vm, np.zeros((0, 2), int))
    assert VM_PERCENTILE == 99.0
    assert vm_norm([piece]).vmax == pytest.approx(np.percentile(vm, 99.0))
    assert vm_norm([piece]).vmax < 1.0
