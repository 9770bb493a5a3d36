// Slab (body 2 of the disk-on-slab scene, cases/disk_on_slab.toml) for the body-fitted
// cross-check (freefem/tools/fitted_two_body_2d.edp). Parameters (gmsh -setnumber):
// lc mesh size, box [x0, x1] x [y0, y1]. Physical curve ids follow FreeFEM's
// square(): 1 bottom (clamped), 2 right, 3 top (contact side), 4 left; surface 1.
// The point (0, y1) under the initial contact point is a mesh node.
// gmsh -2 -format msh22 -setnumber lc 0.0125 slab.geo -o slab.msh
DefineConstant[ lc = 0.05, x0 = -0.5, x1 = 0.5, y0 = -0.5, y1 = -0.25 ];
Point(1) = {x0, y0, 0, lc};
Point(2) = {x1, y0, 0, lc};
Point(3) = {x1, y1, 0, lc};
Point(4) = {0., y1, 0, lc};
Point(5) = {x0, y1, 0, lc};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 5};
Line(5) = {5, 1};
Curve Loop(1) = {1, 2, 3, 4, 5};
Plane Surface(1) = {1};
Physical Curve(1) = {1};
Physical Curve(2) = {2};
Physical Curve(3) = {3, 4};
Physical Curve(4) = {5};
Physical Surface(1) = {1};
