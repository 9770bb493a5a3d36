"""The contact operator's sanity check (core/nitsche.idp nitscheCheckPoints), written
once for 2D and 3D: a contact point lost from a body's space is found whatever the
direction of its normal."""

import re

import pytest

from driver.runner import freefem_env
from tests.conftest import run_freefem


LOST_POINT_CHECK = """{load}
include "freefem/lib/core/args.idp"
include "freefem/lib/fd{dim}d/dimension.idp"
include "freefem/lib/core/nitsche.idp"
mesh{mesh3} Th = {mesh};
fespace Vh(Th, [{fields}]);
Vh [{unknowns}] = [{unit}];
int lastDof = -1;
for (int i = 0; i < Vh.ndof && lastDof < 0; i++) if (ex[][i] == 1) lastDof = i;
int n1 = Vh.ndof, n = 2*Vh.ndof;
int[int] rows = [0, 0], cols = [lastDof, n1 + lastDof];
real[int] vals = [-1., 1.];
matrix J = [rows, cols, vals];
J.resize(2, n);
{normals}
int lost = 0;
nitscheCheckPoints(Vh, Vh, J, nq, lost)
cout << "lost " << lost << endl;
"""


@pytest.mark.freefem
@pytest.mark.parametrize("dim", [2, 3])
def test_a_lost_contact_point_is_found_whatever_its_normal(tmp_path, dim):
    """core/nitsche.idp nitscheCheckPoints: two contact points whose normal is the last
    axis (flat contact), the first read on both bodies (its row of J gives -u_1.n and
    u_2.n), the second lost (a zero row). The lost one counts once per body: 2. A check
    on the first axis alone sees nothing there (n_x = 0) and counts 0."""
    if dim == 2:
        spec = dict(load="", mesh3="", mesh="square(2, 2)", fields="P1, P1", unknowns="ex, ey", unit="0, 1",
                    normals="real[int] nqx = [0., 0.], nqy = [1., 1.];")
    else:
        spec = dict(load='load "msh3"', mesh3="3", mesh="cube(2, 2, 2)", fields="P1, P1, P1", unknowns="ex, ey, ez", unit="0, 0, 1",
                    normals="real[int] nqx = [0., 0.], nqy = [0., 0.], nqz = [1., 1.];")
    script = tmp_path / "lost.edp"
    script.write_text(LOST_POINT_CHECK.format(dim=dim, **spec))
    proc = run_freefem(script, env=freefem_env())
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lost = int(re.search(r"lost (\d+)", proc.stdout).group(1))
    assert lost == 2
