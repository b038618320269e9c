"""`python -m mazelab ...`: the command line, for an environment whose `mazelab` is not on the PATH."""

import sys

from mazelab.cli.app import main

if __name__ == "__main__":
    sys.exit(main())
