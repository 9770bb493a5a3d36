"""The compiled pressure recovery (freefem/plugins/pressure_recovery.cpp, through
core/pressure_recovery.idp) against the fit it states, computed here by brute force
over all pairs of points: on contact points whose radii differ by a factor of eight
from one point to the next (as on a graded mesh, where the plugin's cells follow the
smallest radius and each point reads the cells its own radius reaches), in 3D and 2D.
The closed-form accuracy of the fit is tests/test_outputs.py's."""

import numpy as np
import pytest
import scipy.linalg

from conftest import run_freefem

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)

# Points on the lower part of a sphere (3D, a Fibonacci spiral) or a circle (2D),
# unit normals outward, weights and radii alternating, a Hertz-like pressure on the
# cap below z (y) = -0.2 with a ripple that the fit averages.
RECOVERY_SCRIPT = r"""
include "freefem/lib/core/args.idp"
include "freefem/lib/core/pressure_recovery.idp"
int dim = argInt("dim", 3), n = argInt("n", 3000), degree = argInt("degree", 1), activeOnly = argInt("active_only", 0);
int ramp = argInt("ramp", 0);   /* 1: a ramp rising from 0 near one end of the arc (2D) */
string out = argString("out", "recovery.txt");
real R = 0.25;
real[int] qx(n), qy(n), qz(n), nx(n), ny(n), nz(n), qw(n), p(n), rad(n), rec(n);
for (int i = 0; i < n; i++) {
    real c, s, z;
    if (dim == 3) {
        z = -1. + 0.9*(i + 0.5)/n;            /* lower part of the sphere */
        real rr = sqrt(1. - z^2), phi = i*pi*(3. - sqrt(5.));
        nx[i] = rr*cos(phi); ny[i] = rr*sin(phi); nz[i] = z;
    } else {
        real t = -pi/2 + 1.4*pi*(i + 0.5)/n - 0.7*pi;
        nx[i] = cos(t); ny[i] = sin(t); nz[i] = 0;
    }
    qx[i] = R*nx[i]; qy[i] = R*ny[i]; qz[i] = R*nz[i];
    qw[i] = (1. + 0.5*(i % 3))/n;
    rad[i] = (i % 2 == 0) ? 0.012 : 0.096;
    real low = (dim == 3) ? qz[i] : qy[i], r2 = (dim == 3) ? qx[i]^2 + qy[i]^2 : qx[i]^2;
    p[i] = (low < -0.2) ? max(0., 1. - r2/0.12^2)*(1. + 0.1*sin(37.*i)) : 0.;
    if (ramp) p[i] = max(0., (i - 0.02*n)/n);
}
if (degree == 1 && activeOnly == 0) { pressureRecovery(dim, qx, qy, qz, nx, ny, nz, qw, p, rad, rec) }
else { pressureRecoveryWith(dim, degree, activeOnly, qx, qy, qz, nx, ny, nz, qw, p, rad, rec) }
ofstream f(out);
f.precision(17);
for (int i = 0; i < n; i++)
    f << qx[i] << " " << qy[i] << " " << qz[i] << " " << nx[i] << " " << ny[i] << " " << nz[i] << " "
      << qw[i] << " " << p[i] << " " << rad[i] << " " << rec[i] << endl;
"""


def quadratic_constant(basis, w, p):
    """The constant term of the weighted least-squares quadratic on the basis columns (1, s,
    (t)), or None where the plugin's elimination finds a pivot below 1e-10 of the largest
    diagonal entry (it then keeps the plane's value)."""
    cols = [basis[:, 0], basis[:, 1]] + ([basis[:, 2]] if basis.shape[1] == 3 else [])
    if len(cols) == 3:
        s, t = cols[1], cols[2]
        cols += [s * s, s * t, t * t]
    else:
        cols += [cols[1] * cols[1]]
    q = np.column_stack(cols)
    m, b = q.T @ (w[:, None] * q), q.T @ (w * p)
    upper = scipy.linalg.lu(m)[2]
    if np.abs(np.diag(upper)).min() <= 1e-10 * np.abs(np.diag(m)).max():
        return None
    return np.linalg.solve(m, b)[0]


def brute_force(dim, x, normal, w, p, radius, degree=1, active_only=False, clip=True):
    """The fit of core/pressure_recovery.idp at every point, over all points within its radius
    (degree 2: the quadratic's constant term; active_only: 0 where p is 0; clip: at 0)."""
    rec = np.zeros(len(p))
    for i in range(len(p)):
        if active_only and not p[i] > 0:
            continue
        d = x - x[i]
        near = np.einsum("ij,ij->i", d, d) < radius[i] ** 2 * (1 + 1e-12)
        n = normal[i]
        if dim == 2:
            tangents = [np.array([-n[1], n[0], 0.0])]
        else:
            axis = np.eye(3)[np.argmin(np.abs(n))]
            t1 = np.cross(n, axis)
            t1 /= np.linalg.norm(t1)
            tangents = [t1, np.cross(n, t1)]
        basis = np.column_stack([np.ones(near.sum())] + [d[near] @ t / radius[i] for t in tangents])
        m = basis.T @ (w[near][:, None] * basis)
        b = basis.T @ (w[near] * p[near])
        a = b[0] / m[0, 0]
        if np.linalg.det(m) > 1e-8 * m[0, 0] ** (dim):
            a = np.linalg.solve(m, b)[0]
        if degree == 2:
            quadratic = quadratic_constant(basis, w[near], p[near])
            a = a if quadratic is None else quadratic
        rec[i] = max(a, 0.0) if clip else a
    return rec


@pytest.mark.parametrize("dim, n", [(3, 3000), (2, 1500)])
def test_recovery_matches_the_brute_force_fit_on_mixed_radii(tmp_path, dim, n):
    script, out = tmp_path / "recovery.edp", tmp_path / "recovery.txt"
    script.write_text(RECOVERY_SCRIPT)
    proc = run_freefem(script, "-dim", dim, "-n", n, "-out", out)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    data = np.loadtxt(out)
    x, normal, w, p, radius, rec = data[:, 0:3], data[:, 3:6], data[:, 6], data[:, 7], data[:, 8], data[:, 9]
    expected = brute_force(dim, x, normal, w, p, radius)
    assert (p > 0).sum() > 50 and (expected > 0).sum() > 50   # the check has a contact zone
    assert np.abs(rec - expected).max() <= 1e-12 * p.max()


@pytest.mark.parametrize("dim, n", [(3, 3000), (2, 1500)])
def test_quadratic_recovery_on_the_active_points_matches_the_brute_force_fit(tmp_path, dim, n):
    """The 3D recovery's options (pressureRecoveryWith: a quadratic fit, 0 at the inactive
    points) against the same fit by brute force, in 3D and 2D."""
    script, out = tmp_path / "recovery.edp", tmp_path / "recovery.txt"
    script.write_text(RECOVERY_SCRIPT)
    proc = run_freefem(script, "-dim", dim, "-n", n, "-degree", 2, "-active_only", 1, "-out", out)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    data = np.loadtxt(out)
    x, normal, w, p, radius, rec = data[:, 0:3], data[:, 3:6], data[:, 6], data[:, 7], data[:, 8], data[:, 9]
    expected = brute_force(dim, x, normal, w, p, radius, degree=2, active_only=True)
    assert (expected > 0).sum() > 50
    assert (rec[p == 0] == 0).all()
    assert np.abs(rec - expected).max() <= 1e-13 * p.max()   # measured 4.1e-15 (3D), 2.5e-15 (2D)


def test_the_recovered_pressure_is_clipped_at_zero(tmp_path):
    """Where the window is one-sided (the first points of the arc) and a ramp of pressure
    starts inside it, the fitted line goes below 0 at the point (a hinge's least-squares
    line, extrapolated); the recovery there is 0, elsewhere the fit (2D: the 3D fit ends in
    the same clip)."""
    script, out = tmp_path / "recovery.edp", tmp_path / "recovery.txt"
    script.write_text(RECOVERY_SCRIPT)
    proc = run_freefem(script, "-dim", 2, "-n", 1500, "-ramp", 1, "-out", out)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    data = np.loadtxt(out)
    x, normal, w, p, radius, rec = data[:, 0:3], data[:, 3:6], data[:, 6], data[:, 7], data[:, 8], data[:, 9]
    unclipped = brute_force(2, x, normal, w, p, radius, clip=False)
    assert (unclipped < -1e-4 * p.max()).sum() >= 10     # the fit goes below 0 at 11 points (down to -1.2 % of max p)
    assert rec.min() == 0 and np.abs(rec - np.maximum(unclipped, 0)).max() <= 1e-12 * p.max()
