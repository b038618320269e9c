"""mazelab: a robot lost in a maze, found by particle filters (SIR, APF, RPF) and the exact grid filter;
an extended Kalman filter as the baseline.

The paper's three files (particle_filter.py, draw.py, main.py) are faces over this package. Its
modules, each with one job, and the order in which they import one another (the model at the bottom,
the command line at the top, the drawing never imported by the model): docs/architecture.md, "Where
things are".
"""

from typing import Any

__version__ = "0.3.0"


def __getattr__(name: str) -> Any:
    """`mazelab.study(...)` and `mazelab.study_plan(...)`, the Python entry points of studies
    (mazelab.experiments.api), imported on first use so that `import mazelab` stays light."""
    if name in ("study", "study_plan", "StudyResult"):
        from mazelab.experiments import api

        return getattr(api, name)
    raise AttributeError(f"module 'mazelab' has no attribute {name!r}")
