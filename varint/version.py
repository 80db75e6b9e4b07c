"""The package's version (one place: the HDF5 files, the CLI and ``varint.__version__`` read it here)."""

__version__ = "0.2.0.dev0"
