"""The exercise: a student writes Algorithm 4's four parts (predict, weigh, resample, estimate) in a
subclass of StudentFilter; `mazelab exercise check` grades each part and the whole filter against the
exact posterior.

    from mazelab.exercise import OUTSIDE_PENALTY, ROBOT_SPEED, StudentFilter

Modules: student (StudentFilter, the wiring), template (the catalogues of the languages, and the files
`exercise new` and `exercise autograder` write), inputs (the inputs of a seed), parts (a row of the
report, the verdict on each part and on the whole filter), report (the checker, the grader's reference
runs, the text, the student's own checks), kit (the student kit, and copied code found), child and
sandbox (where and how a submission runs: a bubblewrap sandbox holding only the student kit, and the
messages it sends), grading (a class's folder), selfcheck (the notebook's names for the own checks).
"""

from __future__ import annotations

from mazelab.constants import OUTSIDE_PENALTY, ROBOT_SPEED
from mazelab.exercise.student import PARTS, PartError, StudentFilter

__all__ = ["OUTSIDE_PENALTY", "PARTS", "ROBOT_SPEED", "PartError", "StudentFilter"]
