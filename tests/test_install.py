"""make's virtual environment (Makefile, setup-python): made with PYTHON, made anew for
another PYTHON, left alone when make did not make it, and checked without starting
Python while everything is in place.

Each test runs the Makefile in a scratch folder with stand-in interpreters: shell
scripts that log their arguments and, for `-m venv DIR`, make DIR/bin/python a link
to themselves, so no package is installed. setup-system (apt-get) is skipped with -o.
The real install is proved by CI (.ci/debian12: make case on a plain Debian 12).
"""

import os
import shutil
import subprocess

import pytest

from driver.runner import REPO

FAKE_PYTHON = """#!/bin/sh
echo "$0 $*" >> {log}
if [ "$1" = -m ] && [ "$2" = venv ]; then mkdir -p "$3/bin" && ln -sf "$0" "$3/bin/python"; fi
exit 0
"""


@pytest.fixture
def checkout(tmp_path):
    for name in ("Makefile", "requirements.txt", "pyproject.toml"):
        shutil.copy(REPO / name, tmp_path)
    return tmp_path


def fake_python(folder, name):
    path = folder / name
    path.write_text(FAKE_PYTHON.format(log=folder / "python.log"))
    path.chmod(0o755)
    return path


def setup_python(checkout, python):
    return subprocess.run(["make", "-s", "-o", "setup-system", "setup-python", f"PYTHON={python}"],
                          cwd=checkout, capture_output=True, text=True)


def started(checkout):
    log = checkout / "python.log"
    lines = log.read_text().splitlines() if log.exists() else []
    log.unlink(missing_ok=True)
    return lines


def test_a_venv_that_make_did_not_make_is_refused_and_left_alone(checkout):
    python = fake_python(checkout, "python3")
    (checkout / ".venv" / "bin").mkdir(parents=True)
    (checkout / ".venv" / "mine.txt").write_text("keep")
    proc = setup_python(checkout, python)
    assert proc.returncode != 0
    assert "ERROR: .venv exists but make setup did not make it: move it aside" in proc.stdout
    assert sorted(p.name for p in (checkout / ".venv").iterdir()) == ["bin", "mine.txt"]
    assert (checkout / ".venv" / "mine.txt").read_text() == "keep"
    assert started(checkout) == []


def test_a_missing_interpreter_is_one_line(checkout):
    proc = setup_python(checkout, checkout / "no-such-python")
    assert proc.returncode != 0
    assert proc.stdout.strip() == f"ERROR: no interpreter {checkout / 'no-such-python'} (set PYTHON=/path/to/python3)"
    assert not (checkout / ".venv").exists()


def test_the_venv_is_made_once_then_checked_without_starting_python(checkout):
    python = fake_python(checkout, "python3")
    assert setup_python(checkout, python).returncode == 0
    assert started(checkout)[0] == f"{python} -m venv .venv"
    assert (checkout / ".venv" / ".made-by-make-setup").read_text() == f"{python}\n"
    assert (checkout / ".venv" / "bin" / "python").resolve() == python.resolve()
    # the stand-in writes no stamp: write one as the look-up would, newer than requirements.txt
    stamp, requirements = checkout / ".venv" / ".setup-python", checkout / "requirements.txt"
    listed = checkout / "listed.py"
    listed.write_text("")
    stamp.write_text(f".venv/bin/python\n{listed}\n")
    os.utime(requirements, (1e9, 1e9))
    os.utime(checkout / "pyproject.toml", (1e9, 1e9))
    assert setup_python(checkout, python).returncode == 0
    assert started(checkout) == []
    # the venv's own interpreter counts as the same PYTHON
    assert setup_python(checkout, checkout / ".venv" / "bin" / "python").returncode == 0
    assert started(checkout) == []
    # a file the stamp lists gone, or a newer requirements.txt: the look-up runs, the venv stays
    listed.unlink()
    assert setup_python(checkout, python).returncode == 0
    calls = started(checkout)
    assert calls and not any("-m venv" in call for call in calls)
    listed.write_text("")
    os.utime(requirements, (stamp.stat().st_mtime + 10,) * 2)
    assert setup_python(checkout, python).returncode == 0
    calls = started(checkout)
    assert calls and not any("-m venv" in call for call in calls)


def test_another_python_makes_the_venv_anew(checkout):
    first, second = fake_python(checkout, "python3"), fake_python(checkout, "python3.other")
    assert setup_python(checkout, first).returncode == 0
    (checkout / ".venv" / "left-by-the-first.txt").write_text("")
    started(checkout)
    assert setup_python(checkout, second).returncode == 0
    assert started(checkout)[0] == f"{second} -m venv .venv"
    assert (checkout / ".venv" / ".made-by-make-setup").read_text() == f"{second}\n"
    assert (checkout / ".venv" / "bin" / "python").resolve() == second.resolve()
    assert not (checkout / ".venv" / "left-by-the-first.txt").exists()
