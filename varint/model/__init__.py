"""The model of a scene: its blocks of unknowns, its terms and forces (:mod:`varint.model.model`), and its static
equilibria (:mod:`varint.model.statics`)."""
