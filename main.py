"""The lab's example and its command line: `python main.py` runs the paper's example (a lost robot,
the SIR filter, 1500 particles, 200 steps); `python main.py --help` lists the commands (run, compare,
study, maze, bench). The same commands run from any folder as `mazelab ...`.

The example, step by step, is mazelab/cli/replay.py, `run_one` (`run` with every default); every
command is in mazelab/cli/.
"""

import sys

try:
    from mazelab.cli.app import main
except ModuleNotFoundError as missing:  # run before installing: say what to do, not a traceback
    sys.exit(f"error: {missing.name} is not installed; run `uv run main.py`, or pip install -e . (see README.md)")

if __name__ == "__main__":
    sys.exit(main())
