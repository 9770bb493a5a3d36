// x^2 and x^3 as a FreeFEM script computes them, for the plugins that repeat a
// script's arithmetic to the bit (curved_cells.cpp, pressure_recovery.cpp): FreeFEM
// evaluates x^n through the C library's pow, and a compiler that sees pow(x, 2.)
// turns it into x*x, which differs from pow in the last bit for some x. The
// exponents are volatile so that the compiler cannot see them.
#ifndef FDCONTACT_SCRIPT_POWERS_HPP
#define FDCONTACT_SCRIPT_POWERS_HPP

#include <cmath>

static volatile double scriptExponentTwo = 2., scriptExponentThree = 3.;
inline double sq(double x) { return std::pow(x, scriptExponentTwo); }
inline double cube(double x) { return std::pow(x, scriptExponentThree); }

#endif
