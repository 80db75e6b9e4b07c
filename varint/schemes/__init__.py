"""Time-stepping schemes: each takes a model's state to the next one (docs/theory.md §4, §12a-§12b)."""
