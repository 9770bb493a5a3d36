"""Thin Python driver for the FreeFEM fictitious-domain Nitsche contact package
(installed as `fdcontact`; in a checkout also importable as `driver`).

It validates scene files, launches FreeFEM, parses the results FreeFEM writes,
and makes tables and plots. It never recomputes what FreeFEM computes. From Python:
`run(scene, ...)` returns a `Run`; `Scene` builds and validates a scene (driver/api.py).
"""
from .api import FreeFemError, NewtonError, Run, Scene, SceneError, DriverError, run

__version__ = "0.1.0"
__all__ = ["run", "Run", "Scene", "DriverError", "SceneError", "NewtonError", "FreeFemError", "__version__"]
