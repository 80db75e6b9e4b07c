"""The lattice: Lie-group utilities for the frames (Cayley map), the fluid parcels on a straight tube and the labels
on a moving centreline (Catmull-Rom).  Knows no scene, no term, no scheme (docs/architecture.md)."""
