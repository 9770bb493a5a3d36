"""The tables every scene has whatever its script: [scene] (name, script, description, units)
and [limits]; the script modules and the scene loader both read them (driver/scene.py)."""

import re

from .errors import SceneError
from .schema import Field, described, positive

SAFE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}")


@described("1-100 letters, digits, _ - ., not starting with . or -")
def safe_name(value):
    """A scene name becomes part of a folder name: no path separators, quotes or spaces."""
    if not SAFE_NAME.fullmatch(value):
        return "must be 1-100 letters, digits, '_', '-' or '.', not starting with '.' or '-'"
    return None


safe_name.flag_rule = "name"   # core/args.idp checks the same pattern (argSafeName)


SCENE_HEADER = {
    "name": Field("str", flag="name", check=safe_name, doc="scene name, used for run folders"),
    "script": Field("str", doc="FreeFEM top-level script (without .edp) that solves the scene: fd_contact_2d, "
                               "fd_contact_3d or contact_foundation_2d"),
    "description": Field("str", default="", doc="free text, kept in scene.json"),
    "units": Field("tree", default={}, doc="the scene's units, for labels only: { length = \"mm\", force = "
                                          "\"N\", stress = \"MPa\" } (any consistent system; echoed in results.json "
                                          "and used by the plots' axes)"),
}
UNIT_KEYS = ("length", "force", "stress")


def check_units(units, source):
    """The [scene] units table: names of at most 20 printable characters for length, force, stress."""
    if not isinstance(units, dict):
        raise SceneError(f"{source}: key 'scene.units': expected a table {{ length = \"m\", ... }}")
    for key, value in units.items():
        if key not in UNIT_KEYS:
            raise SceneError(f"{source}: key 'scene.units.{key}': unknown (known: {', '.join(UNIT_KEYS)})")
        if not isinstance(value, str) or not 0 < len(value) <= 20 or not value.isprintable():
            raise SceneError(f"{source}: key 'scene.units.{key}': a unit name of 1-20 printable characters, "
                             f"got {str(value)[:30]!r}")
    return units


# What a run may take (the driver stops a run beyond them: exit 2). Not sent to FreeFEM.
LIMITS = {
    "time_s": Field("float", default=7200.0, check=positive, unit="s",
                    doc="wall-time limit of the FreeFEM run; the run is stopped beyond it (exit 2)"),
    "memory_mb": Field("float", default=None, check=positive, unit="MiB",
                       doc="resident-memory limit of the FreeFEM run (default: 95 % of the memory available "
                           "when it starts); the run is stopped beyond it (exit 2)"),
    "gmsh_s": Field("float", default=60.0, check=positive, unit="s",
                    doc="wall-time limit of each gmsh run (gmsh shapes, gmsh meshes)"),
}
