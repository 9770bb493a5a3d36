// A cam-like closed outline for cases/cam_on_slab.toml: a spline through eight
// points around (0, 0.02), lowest point (0, -0.2).
Point(1) = {0.0, -0.2, 0};
Point(2) = {0.16, -0.13, 0};
Point(3) = {0.24, 0.02, 0};
Point(4) = {0.17, 0.17, 0};
Point(5) = {0.0, 0.24, 0};
Point(6) = {-0.17, 0.17, 0};
Point(7) = {-0.24, 0.02, 0};
Point(8) = {-0.16, -0.13, 0};
Spline(1) = {1, 2, 3, 4, 5, 6, 7, 8, 1};
Curve Loop(1) = {1};
Plane Surface(1) = {1};
