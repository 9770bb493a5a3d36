"""One source of truth for parameters: the driver's flags are the keys the scripts read.

Each solver script prints its keys with their embedded defaults (-list_options 1).
For the default scene of each script, every flag the driver sends must be a key the
script reads, with the scene's value as the script's default (so a direct run on
defaults computes the default scene). Keys only a direct run uses are listed here
by name: a new script key must either be reachable from a scene or be added below.
"""

import json
import re
import subprocess

import pytest

from lab.readme import script_schema
from driver.scene import load_scene
from driver.schema import schema_flags
from tests.conftest import REPO

DIRECT_ONLY = {
    # output folder and the listing itself; the driver always passes -outdir
    "common": {"outdir", "list_options"},
    # the adaptation's largest element (defaults to the initial step)
    "fd_contact_2d": {"adapt_hmax"},
    # the centre-cut plane, the grading point (sent when mesh.grade_h > 0)
    "fd_contact_3d": {"cut_y", "grade_x", "grade_y", "grade_z"},
    # errors against a saved reference (sent when reference.folder is set) and its self-test shift
    "contact_foundation_2d": {"reference", "error_shift_x", "error_shift_y"},
}

SCENES = ["cases/disk_on_slab.toml", "cases/ball_on_slab.toml", "cases/square_slip_separation.toml"]


def script_options(script, degree):
    proc = subprocess.run(["FreeFem++", "-nw", "-v", "0", f"freefem/{script}.edp", f"-Ddegree={degree}",
                           "-list_options", "1"], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    line = next(line for line in proc.stdout.splitlines() if line.startswith("OPTIONS:"))
    options = {}
    for item in line.split()[1:]:
        key, _, value = item.partition("=")
        options.setdefault(key, value)   # a key read twice: its first default
    return options


def same_value(driver_value, script_value):
    try:
        a, b = float(driver_value), float(script_value)
    except ValueError:
        return driver_value == script_value
    return abs(a - b) <= 1e-5 * max(abs(a), abs(b), 1e-300)


@pytest.mark.freefem
@pytest.mark.parametrize("case", SCENES)
def test_driver_flags_are_the_script_keys_with_the_scene_as_default(case):
    scene, module = load_scene(REPO / case)
    script = scene["scene"]["script"]
    args = module.freefem_args(scene)
    assert args[0] == f"-Ddegree={scene['method']['degree']}"
    sent = dict(zip(args[1::2], args[2::2]))
    assert all(key.startswith("-") for key in sent), args
    options = script_options(script, scene["method"]["degree"])
    unread = [key for key in sent if key[1:] not in options]
    assert unread == [], f"the driver sends flags {script} never reads"
    differing = {key: (value, options[key[1:]]) for key, value in sent.items()
                 if not same_value(value, options[key[1:]])}
    assert differing == {}, f"(driver, script default) differ for {case}"
    not_sent = set(options) - {key[1:] for key in sent}
    assert not_sent == DIRECT_ONLY["common"] | DIRECT_ONLY[script]


@pytest.mark.parametrize("case", SCENES + ["cases/punch.toml", "cases/sphere_on_sphere.toml"])
def test_every_flag_sent_is_named_by_the_schema(case):
    """One source of names: a flag the driver sends is declared (or derived) by a schema key."""
    scene, module = load_scene(REPO / case)
    named = schema_flags(script_schema(module))
    patterns = [re.compile(re.escape(name).replace(r"\{i\}", r"\d+") + "$") for name in named]
    sent = module.freefem_args(scene)[1::2]
    assert [flag for flag in sent if not any(p.match(flag[1:]) for p in patterns)] == []


@pytest.mark.freefem
def test_3d_contact_points_follow_the_degree_by_default(tmp_path):
    """contact_qp 0 (the scene default) means 3 points per interface triangle for P1, 6 for P2."""
    for degree, points in ((1, 3), (2, 6)):
        out = tmp_path / f"p{degree}"
        proc = subprocess.run(["FreeFem++", "-nw", "-v", "0", "freefem/fd_contact_3d.edp", f"-Ddegree={degree}",
                               "-nx", "4", "-estimators", "0", "-vtu", "0", "-csv", "0", "-outdir", str(out)],
                              cwd=REPO, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        assert json.loads((out / "results.json").read_text())["contact_points"] == points
