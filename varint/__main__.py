import sys

from .cli import main

# the guard keeps worker processes that re-import the main module (multiprocessing's spawn, used by
# Dask's local cluster in `varint sweep`) from running the command line again
if __name__ == "__main__":
    sys.exit(main())
