"""The student's own checks, in the student's own process: what `python my_filter.py` prints
(`progress`: the parts still to write, and the written ones checked), the notebook's check cell after
each part (`check_part`), and its last cell (`check_and_print`: every part and the whole filter). The
same inputs and verdicts as the grade (mazelab.exercise.report, where they live), but nothing isolates
them: they are for finding bugs, the grade is `mazelab exercise check`, which runs the code in a
process of its own."""

from mazelab.exercise.report import check_and_print, check_command, check_part, progress

__all__ = ["check_and_print", "check_command", "check_part", "progress"]
