"""The mass term's share of a floating body's balance is integrated on the solve's own
cut geometry (fd2d/geometry.idp fdBodyIntegral, fd3d/geometry.idp fdBodyIntegral).

Tested with translations, the discrete equations of body 1 say load + contact + pins +
mass = 0, so the part of the load the contact does not carry (balance_error) is the
pins' and the mass term's force: |pins_force + mass_force| / |load| = balance_error,
up to the Newton's residual. On the curved geometry this closes only if the mass force
is integrated on the curved cells, as the assembly does; the P1 cut left it open by
7.0e-3 (2D, NX = 20) and 0.126 (3D, P2 nx = 8) of itself.
"""

import json

import pytest
import numpy as np

from tests.conftest import run_freefem

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)


def closure(tmp_path, script, *args):
    out = tmp_path / script.replace(".edp", "")
    proc = run_freefem(script, *args, "-geometry", "curved", "-estimators", 0, "-vtu", 0, "-csv", 0, "-outdir", out)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    balance = json.loads((out / "results.json").read_text())["balance"]
    carried = np.linalg.norm(np.add(balance["mass_force"], balance["pins_force"]))
    assert balance["balance_error"] > 1e-9   # the mass term does carry a part of the load
    return abs(carried / np.linalg.norm(balance["load_body1"]) - balance["balance_error"]) / balance["balance_error"]


def test_mass_share_closes_the_balance_on_the_curved_geometry_2d(tmp_path):
    assert closure(tmp_path, "fd_contact_2d.edp", "-nx", 20) < 5e-5                  # measured 3.1e-6


def test_mass_share_closes_the_balance_on_the_curved_geometry_3d(tmp_path):
    assert closure(tmp_path, "fd_contact_3d.edp", "-Ddegree=2", "-nx", 8) < 2e-3    # measured 4.6e-4
