// Disk (body 1 of the disk-on-slab scene, cases/disk_on_slab.toml) for the body-fitted
// cross-check (freefem/tools/fitted_two_body_2d.edp). Parameters (gmsh -setnumber):
// lc mesh size, cx cy centre, r radius. Physical ids: curve 1 = the whole circle
// (contact boundary Gamma_1C), surface 1. The centre, the point (cx, cy + 0.4 r)
// (the second x-fixing point, (0, 0.1) for r = 0.25) and the lowest point
// (cx, cy - r) (first contact point) are mesh nodes.
// gmsh -2 -format msh22 -setnumber lc 0.0125 disk.geo -o disk.msh
DefineConstant[ lc = 0.05, cx = 0., cy = 0., r = 0.25 ];
Point(1) = {cx, cy, 0, lc};
Point(2) = {cx + r, cy, 0, lc};
Point(3) = {cx, cy + r, 0, lc};
Point(4) = {cx - r, cy, 0, lc};
Point(5) = {cx, cy - r, 0, lc};
Point(6) = {cx, cy + 0.4*r, 0, lc};
Circle(1) = {2, 1, 3};
Circle(2) = {3, 1, 4};
Circle(3) = {4, 1, 5};
Circle(4) = {5, 1, 2};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
Point{1, 6} In Surface{1};
Physical Curve(1) = {1, 2, 3, 4};
Physical Surface(1) = {1};
