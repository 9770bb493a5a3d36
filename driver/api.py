"""The package from Python: `fdcontact.run(scene, ...)` runs a scene and returns a `Run`;
`fdcontact.Scene` builds and validates a scene in code and writes it as TOML.

    import fdcontact
    run = fdcontact.run("cases/disk_on_slab.toml", out="runs/disk", mesh__nx=40)
    run.results["contact"]["max_pressure_recovered"]
    run.pressure          # contact_pressure.csv as a DataFrame
    run.newton            # one row per Newton iteration
    bodies = run.bodies()  # meshio meshes of body 1 and body 2

Errors are the command line's: SceneError (bad input, exit code 2), NewtonError (a
numerical failure, 3), FreeFemError (FreeFEM or the system, 4), each with the same
one-line message; `error.exit_code` holds the code.
"""

import copy
from pathlib import Path

from .errors import DriverError, FreeFemError, NewtonError, SceneError
from .scene import apply_override, load_scene_data, parse_toml, read_text_file, toml_text

__all__ = ["run", "Run", "Scene", "DriverError", "SceneError", "NewtonError", "FreeFemError"]


class Scene:
    """A scene's tables, from a TOML file (a path), a TOML text or a dict. Immutable: `set`
    returns a new Scene. `check()` validates it (SceneError naming the key) and returns the
    validated scene, read-only, with every default filled in (driver.scene.CheckedScene);
    files a scene names (a gmsh shape) are read next to its file, or from `base_dir`
    (default: the working folder)."""

    def __init__(self, source, base_dir=None):
        if isinstance(source, Scene):
            self._data, self.source, self.base_dir = copy.deepcopy(source._data), source.source, source.base_dir
            return
        if isinstance(source, dict):
            self._data, self.source = copy.deepcopy(source), "<scene table>"
            self.base_dir = Path(base_dir or Path.cwd())
        elif isinstance(source, Path) or (isinstance(source, str) and "\n" not in source
                                           and source.strip().endswith(".toml")):
            path = Path(source)
            self._data = parse_toml(read_text_file(path, "scene file"), str(path))
            self.source, self.base_dir = str(path), Path(base_dir or path.parent)
        elif isinstance(source, str):
            self._data, self.source = parse_toml(source, "<scene text>"), "<scene text>"
            self.base_dir = Path(base_dir or Path.cwd())
        else:
            raise SceneError(f"a scene is a TOML file's path, a TOML text or a dict, got {type(source).__name__}")

    @property
    def data(self):
        """A copy of the scene's tables (as given, before validation)."""
        return copy.deepcopy(self._data)

    def set(self, key, value):
        """A new Scene with the dotted `key` set to `value` (as `--set key=value`)."""
        new = Scene(self)
        apply_override(new._data, key.split("."), value, self.source)
        return new

    def check(self, overrides=()):
        """The validated scene (a read-only CheckedScene, defaults filled in) and its script
        module; SceneError if not valid. This Scene is left as it was."""
        return load_scene_data(self._data, self.source, self.base_dir, overrides)

    def to_toml(self):
        return toml_text(self._data)

    def write(self, path):
        """Write the scene as a TOML file (refused over an existing file)."""
        path = Path(path)
        if path.exists():
            raise SceneError(f"{path}: exists; the scene is not written over it")
        path.write_text(self.to_toml())
        return path


def run(scene, out=None, replace=False, overrides=None, **settings):
    """Run a scene (a path, a TOML text, a dict or a Scene) and return its Run.

    Overrides: `overrides={"mesh.nx": 40}` or keyword arguments with `__` for the dots
    (`mesh__nx=40`). `out`: the run folder (default runs/NAME-TIME-HASH under the
    checkout, or under the working folder for an installed package); `replace` replaces
    a previous run there once the new one has converged (as --replace)."""
    from .runner import run_scene

    scene = scene if isinstance(scene, Scene) else Scene(scene)
    items = {**(overrides or {}), **{key.replace("__", "."): value for key, value in settings.items()}}
    for key, value in items.items():
        scene = scene.set(key, value)
    checked, module = scene.check()
    _results, folder, _wall = run_scene(checked, module, out_dir=out, replace=replace)
    return Run(folder)


class Run:
    """A finished run's folder: its results.json as a dict, its tables as DataFrames and its
    bodies as meshes. Reads only the folder's own files."""

    def __init__(self, folder):
        from .plot import read_results

        self.folder = Path(folder)
        self.results = read_results(self.folder)

    def __repr__(self):
        return f"Run({str(self.folder)!r})"

    @property
    def pressure(self):
        """contact_pressure.csv: one row per contact point (pressure >= 0 in compression)."""
        import pandas as pd

        return pd.read_csv(self.folder / "contact_pressure.csv")

    @property
    def newton(self):
        """The Newton history, one row per iteration: residual, active and changed measure."""
        import pandas as pd

        newton = self.results["newton"]
        columns = [k for k in ("residual", "active_measure", "changed_measure") if isinstance(newton.get(k), list)]
        frame = pd.DataFrame({k: newton[k] for k in columns})
        frame.index.name = "iteration"
        return frame

    @property
    def steps(self):
        """One row per solve of an adaptive run (one row without adaptation)."""
        import pandas as pd

        steps = self.results.get("steps", {})
        frame = pd.DataFrame({k: v for k, v in steps.items() if isinstance(v, list)})
        frame.index.name = "step"
        return frame

    def bodies(self, inside=False):
        """{"body1": mesh, "body2": mesh} (meshio) from body1.vtu and body2.vtu. inside=True
        keeps only the cells whose points all lie inside the body (phi <= 0): the cut cells
        straddling the interface are left out, not clipped."""
        import meshio
        import numpy as np

        out = {}
        for name in ("body1", "body2"):
            mesh = meshio.vtu.read(self.folder / self.results.get("outputs", {}).get(f"vtu_{name}", f"{name}.vtu"))
            if inside:
                phi = np.asarray(mesh.point_data["phi"]).reshape(-1)
                masks = [np.all(phi[block.data] <= 0, axis=1) for block in mesh.cells]
                cells = [meshio.CellBlock(block.type, block.data[mask]) for block, mask in zip(mesh.cells, masks)]
                keep = {key: [np.asarray(values)[mask] for values, mask in zip(blocks, masks)]
                        for key, blocks in mesh.cell_data.items()}
                mesh = meshio.Mesh(mesh.points, cells, point_data=mesh.point_data, cell_data=keep)
            out[name] = mesh
        return out

    def plot(self, plane=None, scale=1.0):
        """The run's figures (PNG files in its folder, as `fdcontact plot`); their paths."""
        from .plot import plot_run

        return plot_run(self.folder, plane=plane, scale=scale)

