import sys

from .cli import main

# Guarded: Dask's worker processes are started by multiprocessing's spawn, which
# imports this module again (as __mp_main__) in each new process.
if __name__ == "__main__":
    sys.exit(main())
