"""Outside truths: analytic and ODE-accurate solutions that varint is validated against (Rankine-Hugoniot, the exact
Riemann solver, the traveling shock, beams, pipes conveying fluid, wave dispersion).  They know no lattice, no
scene and no scheme, so that a validation compares two things written independently (docs/architecture.md)."""
