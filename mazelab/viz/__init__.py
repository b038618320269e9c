"""Drawing the lab in Rerun: the views of a run and of a comparison (views), the recording and where it
goes (recording), the viewer processes (processes), colours and layouts (style). The model
never imports this package; a run opens its view (mazelab.simulation.open_run_view). Its public names
are the ones draw.py gathers."""
