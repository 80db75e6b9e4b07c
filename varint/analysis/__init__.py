"""Analysis that needs no time stepping, or reads a run: modes, statics front ends, thresholds, shock measurements."""
