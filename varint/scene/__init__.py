"""Scene files: the schema and its validation, the initial fields, the quantities derived from the keys, the scene
text as data and the standard scenes of the tests and scripts (docs/scenes.md)."""
