"""Progress bars (driver/progress.py) and what `python -m driver run` imports.

No timing here: the costs are measured by make bench (study bench-overhead)."""

import subprocess
import sys

from driver import progress
from driver.runner import REPO
from lab.studies.common import progress as study_progress
from driver.sweep import Progress


def test_no_bar_when_stderr_is_not_a_terminal(capsys):
    assert progress.bar(total=3) is None
    with progress.study_bar("demo"):
        study_progress(1, 2, "first run")
        study_progress(2, 2, "second run")
    assert capsys.readouterr().err.splitlines() == ["[1/2] first run", "[2/2] second run"]


def test_a_study_bar_counts_its_runs(monkeypatch, capsys):
    monkeypatch.setattr(progress, "on_terminal", lambda: True)
    seen = []
    with progress.study_bar("demo"):
        for i in range(1, 4):
            study_progress(i, 3, f"run {i}")
            seen.append(progress._study["bar"].n)
        bar = progress._study["bar"]
    assert seen == [0, 1, 2]          # run i starts when i - 1 are done
    assert bar.n == 3 and progress._study["bar"] is None
    assert "[1/3]" not in capsys.readouterr().err.splitlines()   # the bar shows them, no plain lines


def test_sweep_progress_lines_without_a_terminal(capsys):
    line = Progress("demo", 4, 1)
    line.show(1, 2, 0)
    line.show(1, 2, 0)                # unchanged: no second line
    line.show(4, 0, 1)
    line.close()
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2 and lines[-1].startswith("sweep demo: 4/4 done (1 from earlier runs), 0 running, 1 failed")


def test_sweep_progress_bar_ends_with_its_summary_line(monkeypatch, capsys):
    monkeypatch.setattr(progress, "on_terminal", lambda: True)
    line = Progress("demo", 4, 1)
    assert line.bar is not None and line.bar.n == 1
    line.show(3, 1, 0)
    assert line.bar.n == 3
    line.show(4, 0, 0)
    line.close()
    assert capsys.readouterr().err.splitlines()[-1].startswith("sweep demo: 4/4 done (1 from earlier runs)")


CHECK_IMPORTS = """
import sys
from driver.cli import build_parser
from driver.scene import load_scene
from driver.runner import write_scene_module
args = build_parser(["run", "cases/disk_on_slab.toml"]).parse_args(["run", "cases/disk_on_slab.toml"])
scene, module = load_scene(args.scene, [])
module.freefem_args(scene)
module.scene_module(scene)
heavy = ("pandas", "matplotlib", "meshio", "dask", "distributed", "scipy", "tqdm", "driver.sweep")
print(" ".join(name for name in heavy if name in sys.modules))
"""


def test_a_run_imports_only_what_it_needs():
    proc = subprocess.run([sys.executable, "-c", CHECK_IMPORTS], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""


def test_the_command_list_still_names_the_sweep_commands():
    proc = subprocess.run([sys.executable, "-m", "driver", "--help"], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0 and "sweep-bench" in proc.stdout
