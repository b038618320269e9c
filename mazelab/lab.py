"""The paper's entry points under the names its steps use: `run_model` and `simulate` (both in
mazelab.simulation, one run of one filter)."""

from mazelab.simulation import run_model, simulate

__all__ = ["run_model", "simulate"]
