"""A row of the report, and the rows every check shares: a part that is not written, an error or an
exit of the student's code, an answer of the wrong form, a part that calls the lab's reference
implementation's code, a stage the student's process never reached or ended in."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mazelab.exercise.wire import Message

PASS, FAIL, NOT_WRITTEN, NOT_RUN, NOT_OWN = "pass", "fail", "not written", "not run", "not own work"
COPY_HINT = "write it yourself: a part may not be the lab's reference implementation with its names changed"


@dataclass
class Row:
    """One row of the report: the part (or "whole filter"), its status (pass, fail, not written,
    not run, not own work), what was expected, what came, and a hint when it did not pass."""

    part: str
    status: str
    expected: str
    got: str
    hint: str = ""

    @property
    def passed(self) -> bool:
        return self.status == PASS

    @property
    def not_written(self) -> bool:
        return self.status == NOT_WRITTEN


class BadAnswerError(ValueError):
    """What the student's process sent is not of the form the grader asked for (one line)."""


def take(message: Message, name: str, shape: tuple[int, ...] | None = None, dtype: str = "<f8") -> np.ndarray:
    """The answer's array `name`, of `shape` (None: any) and dtype, or BadAnswerError."""
    array = message.arrays.get(name)
    if array is None:
        raise BadAnswerError(f"no {name!r} in the answer")
    if array.dtype.str != dtype or (shape is not None and array.shape != shape):
        raise BadAnswerError(f"{name!r} is {array.dtype.str} {array.shape}, not {dtype} {shape}")
    return array


def error_of(message: Message) -> dict[str, str] | None:
    """The stage's error as the student's process described it (kind, text), or None."""
    error = message.meta.get("error")
    if error is None:
        return None
    if not isinstance(error, dict) or not isinstance(error.get("text"), str) or not isinstance(error.get("kind"), str):
        raise BadAnswerError("an error that is not a kind and a text")
    return {"kind": error["kind"], "text": error["text"][:600]}


def error_row(part: str, expected: str, error: dict[str, str], hint: str) -> Row:
    """The row of a stage whose student code did not answer: not written, the wrong form, an exit
    of its own, or an error (naming the student's line)."""
    kind, text = error["kind"], error["text"]
    if kind == "not written":
        return Row(part, NOT_WRITTEN, expected, "not implemented", f"write {part} (see its docstring)")
    if kind == "exit":
        return Row(part, FAIL, expected, text, "a part returns its answer; it never ends the program")
    if kind == "answer":
        return Row(part, FAIL, expected, text, hint)
    return Row(part, FAIL, expected, text, hint)


def not_run_row(part: str, expected: str, why: str) -> Row:
    return Row(part, NOT_RUN, expected, "not run", why)


def ended_row(part: str, expected: str, ended: str, output: str) -> Row:
    """The row of the stage in which the student's process ended: how, and its last printed line."""
    last = next((line.strip() for line in reversed(output.splitlines()) if line.strip()), "")
    got = f"the student's process {ended}" + (f"; its last line: {last[:200]}" if last else "")
    hint = "a part returns its answer: no exit, no endless loop, nothing that kills the process"
    return Row(part, FAIL, expected, got, hint)


__all__ = [
    "COPY_HINT",
    "FAIL",
    "NOT_OWN",
    "NOT_RUN",
    "NOT_WRITTEN",
    "PASS",
    "BadAnswerError",
    "Row",
    "ended_row",
    "error_of",
    "error_row",
    "not_run_row",
    "take",
]
