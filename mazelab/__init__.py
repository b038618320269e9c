"""mazelab: a robot lost in a maze, found by particle filters (SIR, APF, RPF) and the exact grid filter;
an extended Kalman filter as the baseline.

The paper's three files (particle_filter.py, draw.py, main.py) are faces over this package. Its
modules, bottom to top (each imports only those above it in this list):

    constants, checks, declaration                            the model's numbers; every guard; a filter's options
    lookup, maze, model, modes                                the model: maze, motion, measurement, modes
    seeding, stops, atomic                                    seeds to random streams; who stopped a run; whole files
    weights, resampling, regularisation, robot                the Weights value, resampling, the RPF's kernel, robot
    contract, smc                                             what every filter provides; the step (SMC)
    recovery, cloud, filters, grid_filter, kalman             the filters (cloud: the template on the model)
    registry                                                  one entry per filter, and a student's own (file.py:Class)
    scenario, collect, simulation                             saved scenarios; the one recording loop; one run
    smoothing, learning                                       the exact smoother on the grid; parameter posterior, PMMH
    invocation                                                how this program was started (printed commands)
    viz/                                                      drawing in Rerun (never imported by the above)
    maze_generator                                            random mazes
    experiments/, bench                                       compare, study, accuracy, kidnapping; the benchmark
    exercise/                                                 the students' exercise: StudentFilter and its checker
    cli/                                                      the command line (`mazelab`, `python main.py`)
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
