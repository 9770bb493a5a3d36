"""Two-body patch test: a block pressed uniformly onto a slab (2D and 3D).

Body 1 fills the box above the slab {y < -0.25} (z in 3D) and carries a traction
(0, -q) on the box top. Both bodies slide freely on the box faces that hold them:
body 1 is held in x on the face x = xmin (and in y on y = ymin in 3D), the slab
in the same way and in y (z) on the box bottom, so that neither is held against
its sideways expansion. The exact solution is affine: sigma_yy = -q in both
bodies, every other stress zero; with E, nu of each body,
  2D (plane strain): u_x = q nu (1 + nu)/E (x + 0.5), u_y = u_y(bottom) - q (1 - nu^2)/E (y - bottom),
  3D:                u_x = q nu/E (x + 0.5), u_y = q nu/E (y + 0.5), u_z = u_z(bottom) - q/E (z - bottom),
the slab's bottom at -0.5 (u = 0 there), the block's at -0.25 on the slab's top.
A consistent Nitsche method reproduces it exactly, for every theta: the contact
points' pressure (1/gamma)[P u - g]_+ is q, their normal jump 0, sigma_n = -q, and
every residual estimator vanishes. The interface y = -0.25 cuts the elements (nx
not a multiple of 4), lambda != mu in both bodies: Lame coefficients swapped, or
nu converted wrongly, give another field. Held in one component on each face, the
bodies count as floating: mass_eps = 1e-12 (what it carries, 1e-13 of the load,
is below the round-off) makes the solver accept them; every rigid motion is held.
"""

import numpy as np
import pytest

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)

Q, E1, NU1, E2, NU2 = 0.01, 1.0, 0.4, 2.0, 0.3

BLOCK_2D = f"""
[scene]
name = "block_on_slab"
script = "fd_contact_2d"
[mesh]
nx = 10
[body1]
shape = {{ type = "box", min = [-0.6, -0.25], max = [0.6, 0.6] }}
E = {E1}
nu = {NU1}
body_force = [0.0, 0.0]
hold = [{{ face = "xmin", components = "x" }}]
load = [{{ face = "ymax", traction = [0.0, {-Q}] }}]
[body2]
shape = "slab"
top = -0.25
E = {E2}
nu = {NU2}
hold = [{{ face = "ymin", components = "y" }}, {{ face = "xmin", components = "x" }}]
[rigid]
mass_eps = 1.0e-12
fix_x_points = []
"""

BLOCK_3D = f"""
[scene]
name = "block_on_slab_3d"
script = "fd_contact_3d"
[mesh]
nx = 6
[body1]
shape = {{ type = "box", min = [-0.6, -0.6, -0.25], max = [0.6, 0.6, 0.6] }}
E = {E1}
nu = {NU1}
body_force = [0.0, 0.0, 0.0]
hold = [{{ face = "xmin", components = "x" }}, {{ face = "ymin", components = "y" }}]
load = [{{ face = "zmax", traction = [0.0, 0.0, {-Q}] }}]
[body2]
shape = "slab"
top = -0.25
E = {E2}
nu = {NU2}
hold = [{{ face = "zmin", components = "z" }}, {{ face = "xmin", components = "x" }}, {{ face = "ymin", components = "y" }}]
[rigid]
mass_eps = 1.0e-12
fix_xy_points = []
"""

# probes: name -> (point, body); the block's top carries the largest displacement
POINTS = {2: {"top": ([0.5, 0.5], 1), "above_contact": ([-0.3, -0.2], 1), "slab": ([0.2, -0.3], 2)},
          3: {"top": ([0.5, 0.5, 0.5], 1), "above_contact": ([-0.3, 0.4, -0.2], 1), "slab": ([0.2, -0.1, -0.3], 2)}}


def scene_text(dim):
    probes = "".join(f"[[probe]]\nname = \"{name}\"\npoint = {point}\nbody = {body}\n"
                     for name, (point, body) in POINTS[dim].items())
    return (BLOCK_2D if dim == 2 else BLOCK_3D) + probes


def exact(point, body):
    """The affine displacement at a point of body 1 or 2 (see the module's text)."""
    *plane, up = point
    young, poisson = (E1, NU1) if body == 1 else (E2, NU2)
    if len(plane) == 1:   # plane strain
        sideways, down = Q * poisson * (1 + poisson) / young, Q * (1 - poisson ** 2) / young
    else:
        sideways, down = Q * poisson / young, Q / young
    if body == 2:
        base, height = 0.0, up + 0.5
    else:
        base, height = exact([0.0] * len(plane) + [-0.25], 2)[-1], up + 0.25
    return np.array([sideways * (c + 0.5) for c in plane] + [base - down * height])


@pytest.fixture(scope="module")
def block(tmp_path_factory, module_scene):
    """block(dim, degree, theta, geometry) -> Run of the block on slab (geometry: the
    method's cut geometry, None for the default)."""
    folder = tmp_path_factory.mktemp("scenes")
    paths = {dim: folder / f"block_{dim}d.toml" for dim in (2, 3)}
    for dim, path in paths.items():
        path.write_text(scene_text(dim))
    return lambda dim, degree, theta, geometry: module_scene(
        paths[dim], f"method.degree={degree}", f"method.theta={theta}",
        *([f"method.geometry='{geometry}'"] if geometry else []))


# Measured on these runs (largest over them): probes 3.2e-10 of the largest
# displacement, penetration 1.9e-11 of it, raw pressure 5.4e-9 of q (1/gamma times
# the round-off of the normal jump), recovered pressure 1.1e-9, sigma_n 8.2e-10,
# eta 1.1e-8 q. A contact law off by 1 %, or a theta term of the wrong sign, leaves a
# penetration of 1e-5 of it and a pressure off by 8 % and more; the 3D estimator
# with inward normals on a loaded box face gave eta = 0.76 q.
# The block's faces are planes, so the P1 cut geometry is exact too: its 3D case runs
# the P1-geometry bulk assembly, which the curved default does not reach.
CASES = [(2, 1, 1, None), (2, 1, 0, None), (2, 1, -1, None), (2, 2, 1, None), (2, 2, -1, None),
         (3, 1, 1, None), (3, 1, -1, None), (3, 1, 1, "p1")]


@pytest.mark.parametrize("dim, degree, theta, geometry", CASES)
def test_block_on_slab_reproduces_the_affine_solution(block, dim, degree, theta, geometry):
    run = block(dim, degree, theta, geometry)
    r = run.results
    # the driver's (E, nu) -> Lame and FreeFEM's Lame -> (E, nu) give the scene's values back
    for body, (young, poisson) in (("body1", (E1, NU1)), ("body2", (E2, NU2))):
        assert r["materials"][body]["E"] == pytest.approx(young, rel=1e-12)
        assert r["materials"][body]["nu"] == pytest.approx(poisson, abs=1e-12)
    scale = np.abs(exact(*POINTS[dim]["top"])).max()
    for name, (point, body) in POINTS[dim].items():
        error = np.abs(np.array(r["probes"][name]) - exact(point, body)).max()
        assert error < 1e-9 * scale, name
    s = run.contact_samples()
    assert r["contact"]["active_measure"] == pytest.approx(1.0, rel=1e-12)
    assert (s.normal_jump - s.gap).abs().max() < 5e-11 * scale
    assert (s.pressure / Q - 1).abs().max() < 2e-8
    assert (s.pressure_recovered / Q - 1).abs().max() < 5e-9
    assert (s.sigma_n / Q + 1).abs().max() < 2.5e-9
    assert r["estimator"]["eta"] < 5e-8 * Q
