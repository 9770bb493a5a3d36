"""Driving fdcontact from Python: a disk pressed on a slab, posed as a dict, run, read back.

Run it with the package installed (`pip install .`, or the checkout's `make setup`):
    python docs/examples/python_api.py OUTDIR
tests/test_package.py runs it. Each step says what a user gets.
"""
import sys
from pathlib import Path

import fdcontact

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("runs/python_api_example")

# 1. A scene is a dict (or a TOML file's path, or a TOML text) with the tables of the
#    scene reference (docs/scenes.md). Scene validates it without running anything.
scene = fdcontact.Scene({
    "scene": {"name": "api_disk_on_slab", "script": "fd_contact_2d", "units": {"length": "m", "stress": "Pa"}},
    "mesh": {"nx": 24},
    "body1": {"shape": {"type": "disk", "centre": [0.0, 0.0], "radius": 0.25}, "E": 2.6, "nu": 0.3,
              "body_force": [0.0, -0.1]},
    "body2": {"shape": {"type": "half_plane", "point": [0.0, -0.25], "normal": [0.0, 1.0]}, "E": 2.6, "nu": 0.3,
              "hold": [{"face": "ymin"}]},
    "rigid": {"fix_x_points": [0.0, 0.0, 0.0, 0.1]},
    "method": {"degree": 2},
})
checked, _ = scene.check()
print("validated; theta defaults to", checked["method"]["theta"])

# 2. A bad value raises the command line's error, with its exit code.
try:
    scene.set("mesh.nx", 1).check()
except fdcontact.SceneError as error:
    print(f"refused (exit code {error.exit_code}): {error}")

# 3. Run it (overrides as keywords, `__` for the dots) and read the results.
run = fdcontact.run(scene, out=out, output__vtu=True)
contact = run.results["contact"]
print(f"force on the disk {contact['force_on_body1']}, recovered peak pressure "
      f"{contact['max_pressure_recovered']:.4g} {run.results['units']['stress']}")

# 4. Tables as pandas DataFrames: the pressure along the contact, the Newton history.
active = run.pressure[run.pressure.active == 1]
print(f"{len(active)} active contact points; Newton took {len(run.newton)} iterations, "
      f"final residual {run.newton.residual.iloc[-1]:.1e}")

# 5. The bodies as meshio meshes (cells wholly inside each body with inside=True).
bodies = run.bodies(inside=True)
print({name: len(mesh.points) for name, mesh in bodies.items()})

# 6. Where it came from: the package, the commit, FreeFEM's and MUMPS's versions, the command.
print({k: run.results["provenance"][k] for k in ("version", "freefem", "mumps")})
