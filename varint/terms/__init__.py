"""The physics: the terms of the discrete Lagrangian and the non-conservative forces, one module per effect, with
their element kernels and declarations (docs/theory.md §4a).  Terms know no scheme, no driver and no analysis."""
