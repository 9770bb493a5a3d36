"""Two-body patch test: a block pressed uniformly onto a slab (2D and 3D).

Body 1 fills the box above the slab {y < -0.25} (z in 3D) and carries a traction
(0, -q) on the box top; it is held only in x on the face x = xmin (and in y on
y = ymin in 3D), so that it expands sideways freely. The slab (nu = 0) is clamped on
the box bottom. The exact solution is affine: sigma_yy = -q in both bodies, every
other stress zero; the slab u = (0, -q/E2 (y + 0.5)), the block
  2D (plane strain): u_x = q nu (1 + nu)/E1 (x + 0.5), u_y = u2(-0.25) - q (1 - nu^2)/E1 (y + 0.25),
  3D:                u_x = q nu/E1 (x + 0.5), u_y = q nu/E1 (y + 0.5), u_z = u2(-0.25) - q/E1 (z + 0.25).
A consistent Nitsche method reproduces it exactly, for every theta: the contact
points' pressure (1/gamma)[P u - g]_+ is q, their normal jump 0, sigma_n = -q, and
every residual estimator vanishes. The interface y = -0.25 cuts the elements (nx
not a multiple of 4). lambda != mu in the block (nu = 0.4): a material with its
Lame coefficients swapped, or nu converted wrongly, gives another field.
"""

import numpy as np
import pytest

Q, E1, NU1, E2 = 0.01, 1.0, 0.4, 2.0

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
nu = 0.0
hold = [{{ face = "ymin" }}]
[rigid]
mass_eps = 0.0
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
nu = 0.0
hold = [{{ face = "zmin" }}]
[rigid]
mass_eps = 0.0
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
    slab_top = -Q / E2 * 0.25
    if body == 2:
        return np.array([0.0] * len(plane) + [-Q / E2 * (up + 0.5)])
    if len(plane) == 1:
        sideways, down = Q * NU1 * (1 + NU1) / E1, Q * (1 - NU1 ** 2) / E1
    else:
        sideways, down = Q * NU1 / E1, Q / E1
    return np.array([sideways * (c + 0.5) for c in plane] + [slab_top - down * (up + 0.25)])


@pytest.fixture(scope="module")
def block(tmp_path_factory, module_scene):
    """block(dim, degree, theta) -> Run of the block on slab."""
    folder = tmp_path_factory.mktemp("scenes")
    paths = {dim: folder / f"block_{dim}d.toml" for dim in (2, 3)}
    for dim, path in paths.items():
        path.write_text(scene_text(dim))
    return lambda dim, degree, theta: module_scene(paths[dim], f"method.degree={degree}", f"method.theta={theta}")


# Measured on these runs (largest over them): probes 3.1e-10 of the largest
# displacement, penetration 2.0e-11 of it, raw pressure 6.1e-9 of q (1/gamma times
# the round-off of the normal jump), recovered pressure 1.3e-9, sigma_n 4.1e-10,
# eta 1.1e-8 q. A contact law off by 1 %, or a theta term of the wrong sign, leaves a
# penetration of 1e-5 of it and a pressure off by 8 % and more; the 3D estimator
# with inward normals on a loaded box face gave eta = 0.76 q.
CASES = [(2, 1, 1), (2, 1, 0), (2, 1, -1), (2, 2, 1), (2, 2, -1), (3, 1, 1), (3, 1, -1)]


@pytest.mark.parametrize("dim, degree, theta", CASES)
def test_block_on_slab_reproduces_the_affine_solution(block, dim, degree, theta):
    run = block(dim, degree, theta)
    r = run.results
    # the driver's (E, nu) -> Lame and FreeFEM's Lame -> (E, nu) give the scene's values back
    for body, (young, poisson) in (("body1", (E1, NU1)), ("body2", (E2, 0.0))):
        assert r["materials"][body]["E"] == pytest.approx(young, rel=1e-12)
        assert r["materials"][body]["nu"] == pytest.approx(poisson, abs=1e-12)
    scale = np.abs(exact(*POINTS[dim]["top"])).max()
    for name, (point, body) in POINTS[dim].items():
        error = np.abs(np.array(r["probes"][name]) - exact(point, body)).max()
        assert error < 1e-9 * scale, name
    s = run.contact_samples()
    assert r["contact"]["active_length" if dim == 2 else "active_area"] == pytest.approx(1.0, rel=1e-12)
    assert (s.normal_jump - s.gap).abs().max() < 5e-11 * scale
    assert (s.pressure / Q - 1).abs().max() < 2e-8
    assert (s.pressure_recovered / Q - 1).abs().max() < 5e-9
    assert (s.sigma_n / Q + 1).abs().max() < 1.5e-9
    assert r["estimator"]["eta"] < 5e-8 * Q
