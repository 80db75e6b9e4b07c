"""Running a scene: the driver (:class:`varint.run.simulation.Simulation`), HDF5 output and the run loop."""
