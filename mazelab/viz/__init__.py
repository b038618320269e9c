"""Drawing the lab in Rerun: the views of a run and of a comparison, where recordings go, the viewer
processes. The model never imports this package; mazelab.lab hands its views to the simulation."""

from mazelab.simulation import NullView
from mazelab.viz.recording import Recording, heading_vectors
from mazelab.viz.style import DEFAULT_MAX_DRAWN
from mazelab.viz.targets import Visualization
from mazelab.viz.views import Comparison, NullComparison, RunView, open_comparison, open_view

__all__ = [
    "DEFAULT_MAX_DRAWN",
    "Comparison",
    "NullComparison",
    "NullView",
    "Recording",
    "RunView",
    "Visualization",
    "heading_vectors",
    "open_comparison",
    "open_view",
]
