"""The checker: a report of one submission, a row per part and one for the whole filter, from the
inputs of a seed, the values the student's code returned, and the grader's own reference runs.

`check_file(path)` is the grade: the student's code runs in a child process (mazelab.exercise.runner)
with a time limit, and every verdict is made here from the values it returned. A child that ends
in a part (an exit of any code, a signal, a hang, output that is not an answer) fails that part's row,
naming what happened, and a new child goes on with the parts after it (one try per part); a child
that ends while the file is imported fails every row. `check(filter_class)` runs the same work in this
process: the notebook's and `python my_filter.py`'s self-check, which nothing isolates.

Loading problems are the submission's, not a part's: a file that does not import, a missing class, or
a class that is not a StudentFilter raise NotGradableError (one line; `check` exits 2, `grade` gives the
submission a row of that).
"""

from __future__ import annotations

import contextlib
import inspect
import shlex
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mazelab.exercise import child
from mazelab.exercise.inputs import PartInputs, ScenarioInputs, default_seed, draw_part_inputs, draw_scenarios
from mazelab.exercise.layout import format_rows
from mazelab.exercise.likeness import class_source, copied_parts
from mazelab.exercise.offspring import expected_text as resample_expected
from mazelab.exercise.offspring import judge_resample
from mazelab.exercise.outcome import Report
from mazelab.exercise.parts import EXPECTED, judge_estimate, judge_predict, judge_weigh
from mazelab.exercise.rows import COPY_HINT, FAIL, NOT_OWN, NOT_WRITTEN, BadAnswerError, Row, ended_row, not_run_row
from mazelab.exercise.runner import DEFAULT_TIMEOUT, child_request, run_child, submission_copy
from mazelab.exercise.sandbox import sandbox
from mazelab.exercise.student import PARTS
from mazelab.exercise.whole import References, ScenarioFigures, judge_whole, whole_answer
from mazelab.exercise.whole import expected_text as whole_expected
from mazelab.exercise.wire import Message, decode, encode
from mazelab.invocation import command_prefix
from mazelab.plugins import split_spec

STAGES = (*PARTS, "whole")
WHOLE = "whole filter"


class NotGradableError(ValueError):
    """The submission cannot be checked at all: one line naming the file and why."""


@dataclass
class Answers:
    """What the student's process (or processes) gave: the loaded class's description, each stage's
    answer, how a process ended in a stage, why nothing loaded, and what it printed."""

    loaded: dict[str, Any] | None = None
    results: dict[str, Message] = field(default_factory=dict)
    ended: dict[str, str] = field(default_factory=dict)
    problem: str | None = None
    output: str = ""


# -- collecting the answers ---------------------------------------------------------------------------
def collect_isolated(
    path: Path,
    class_name: str | None,
    parts: PartInputs,
    scenarios: list[ScenarioInputs],
    timeout: float,
    stages: tuple[str, ...] = STAGES,
    shown: str = "",
    companions: bool = True,
) -> Answers:
    """Run the stages in child processes, each in the sandbox of the submission's own copy (and the
    Python files beside it, with `companions`); a new child after a stage in which one ended."""
    answers, todo = Answers(), list(stages)
    made = sandbox()
    with submission_copy(path, companions) as run_folder:
        while todo:
            file = made.inside(run_folder, path.name)
            request = child_request(file, class_name, todo, parts, scenarios, shown or path.name)
            run = run_child(request, run_folder, timeout, made)
            answers.output += run.output
            if run.loaded is None:
                answers.problem = f"the student's process {run.ended or 'sent nothing'}"
                return answers
            answers.loaded = run.loaded
            answers.results.update(run.results)
            if run.ended is None or run.loaded.get("error") or not run.loaded.get("student_filter"):
                return answers
            stage = run.stage if run.stage in todo and run.stage not in run.results else None
            stage = stage or next(s for s in todo if s not in run.results)
            answers.ended[stage] = run.ended
            todo = [s for s in todo if s not in run.results and s != stage]
    return answers


def collect_in_process(
    filter_class: type, parts: PartInputs, scenarios: list[ScenarioInputs], stages: list[str]
) -> Answers:
    """Run the stages in this process (a self-check): the same work as the child's."""
    answers, request = Answers(), decode(child_request("", None, stages, parts, scenarios))

    def emit(meta: dict[str, Any], arrays: dict | None = None) -> None:
        message = decode(encode(meta, arrays))  # exactly what a child would send
        if meta["kind"] == "loaded":
            answers.loaded = message.meta
        elif meta["kind"] == "result":
            answers.results[meta["stage"]] = message

    child.serve(request, emit, filter_class)
    return answers


# -- the rows ----------------------------------------------------------------------------------------
def expected_of(stage: str, parts: PartInputs) -> str:
    if stage == "resample":
        return resample_expected(parts)
    return whole_expected() if stage == "whole" else EXPECTED[stage]


def loading_problem(answers: Answers, shown: str) -> str | None:
    """The one line for a submission that cannot be checked at all, or None."""
    loaded = answers.loaded
    if loaded is None:
        return None
    if loaded.get("error"):
        return one_line(loaded["error"])
    if not loaded.get("student_filter"):
        bases = one_line(", ".join(map(str, loaded.get("bases") or [])) or "object", 200)
        return (
            f"{shown}: {one_line(loaded.get('class'), 80)} is not a StudentFilter (it subclasses {bases}); the "
            "exercise grades a subclass of mazelab.exercise.StudentFilter with your own predict, weigh, resample "
            "and estimate"
        )
    return None


def one_line(text: object, limit: int = 600) -> str:
    """What the student's process said, as one line of at most `limit` characters (never a forged line)."""
    return " ".join(str(text).split())[:limit]


@dataclass
class _Judging:
    """What one stage's verdict hands the next: the scheme resample resembles, the whole's figures."""

    parts: PartInputs
    scenarios: list[ScenarioInputs]
    answers: Answers
    references: References
    exact: list
    scheme: str = "systematic"
    figures: list[ScenarioFigures] = field(default_factory=list)


def build_report(
    name: str,
    seed: int,
    parts: PartInputs,
    scenarios: list[ScenarioInputs],
    answers: Answers,
    references: References,
    stages: tuple[str, ...] = STAGES,
    copies: dict[str, str] | None = None,
) -> Report:
    """The report from the answers: each part judged (or failed for how the process ended in it, or
    for being the lab's code: `copies`, mazelab.exercise.likeness), then the whole filter against the
    reference runs."""
    report = Report(name, seed, output=answers.output)
    if answers.problem:
        report.problems.append(answers.problem)
        how = answers.problem.removeprefix("the student's process ")
        report.rows = [ended_row(_label(s), expected_of(s, parts), how, answers.output) for s in stages]
        return report
    judging = _Judging(parts, scenarios, answers, references, [references.exact(s) for s in scenarios])
    for stage in stages:
        row = _stage_row(stage, judging)
        copied = (copies or {}).get(stage)
        if copied and row.status != NOT_WRITTEN:
            row = Row(row.part, NOT_OWN, row.expected, copied, COPY_HINT)
        report.rows.append(row)
    report.figures = judging.figures
    report.problems += [f"{_label(stage)}: the student's process {how}" for stage, how in answers.ended.items()]
    report.problems += [f"{r.part}: {r.got}" for r in report.rows if r.status == NOT_OWN]
    return report


def _label(stage: str) -> str:
    return WHOLE if stage == "whole" else stage


def _stage_row(stage: str, judging: _Judging) -> Row:
    label, expected, answers = _label(stage), expected_of(stage, judging.parts), judging.answers
    if stage in answers.ended:
        return ended_row(label, expected, answers.ended[stage], answers.output)
    message = answers.results.get(stage)
    if message is None:  # it said "done" (or ended) without this stage's answer
        return Row(label, FAIL, expected, "no answer came from the student's process", "a part returns its answer")
    try:
        if stage == "whole":
            return _whole_row(judging, message)
        if stage == "resample":
            row, judging.scheme = judge_resample(judging.parts, message)
            return row
        return {"predict": judge_predict, "weigh": judge_weigh, "estimate": judge_estimate}[stage](
            judging.parts, message
        )
    except BadAnswerError as error:
        return Row(label, "fail", expected, f"an answer the grader cannot read ({error})", "return plain arrays")


def _whole_row(judging: _Judging, message: Message) -> Row:
    results = judging.answers.results
    if any(p in results and _not_written(results[p]) for p in PARTS):
        return not_run_row(WHOLE, whole_expected(judging.scheme), "write every part first")
    estimates = whole_answer(judging.scenarios, message, judging.scheme)
    if isinstance(estimates, Row):
        return estimates
    sir = [judging.references.sir(s, judging.scheme) for s in judging.scenarios]
    exact, sir = [f.result() for f in judging.exact], [f.result() for f in sir]
    row, judging.figures = judge_whole(judging.scenarios, estimates, exact, sir, judging.scheme)
    return row


def _not_written(message: Message) -> bool:
    error = message.meta.get("error")
    return isinstance(error, dict) and error.get("kind") == "not written"


# -- the checks ----------------------------------------------------------------------------------------
def check_file(
    spec: str,
    *,
    seed: int | None = None,
    timeout: float = DEFAULT_TIMEOUT,
    references: References | None = None,
    stages: tuple[str, ...] = STAGES,
    companions: bool = True,
) -> Report:
    """Grade `path/to/file.py[:Class]` in child processes (the given stages: every part and the whole
    filter by default), the Python files beside it copied with it unless `companions` is False (a
    file directly in a class folder: the others are other students'); NotGradableError when it
    cannot be checked."""
    started = time.perf_counter()
    path, class_name = split_spec(spec)
    shown = f"{path}:{class_name}" if class_name else str(path)
    if not path.is_file():
        raise NotGradableError(f"{shown}: no such file {path}" + ("" if path.exists() else " (check the path)"))
    if path.resolve().suffix != ".py":
        raise NotGradableError(f"{shown}: a link to {path.resolve()}, not a Python file")
    seed = default_seed(path.read_bytes()) if seed is None else seed
    parts = draw_part_inputs(seed)
    scenarios = draw_scenarios(seed) if "whole" in stages else []
    references = references or References()
    for scenario in scenarios:
        references.exact(scenario)  # start the exact runs while the student's process works
    answers = collect_isolated(path.resolve(), class_name, parts, scenarios, timeout, stages, shown, companions)
    problem = loading_problem(answers, shown)
    if problem:
        raise NotGradableError(problem)
    said = str((answers.loaded or {}).get("name") or class_name or path.stem)
    name = one_line(said, 80)  # the child's word for its name
    copies = copied_parts(path.read_text(errors="replace"))
    report = finish(build_report(name, seed, parts, scenarios, answers, references, stages, copies))
    report.note = sandbox().note
    report.seconds = time.perf_counter() - started
    return report


def check(filter_class: type, *, seed: int | None = None, stages: tuple[str, ...] = STAGES) -> Report:
    """Check a class in this process (a self-check: nothing isolates it), the given stages (every
    part and the whole filter by default); the seed defaults to one from the class's source, or 0."""
    started = time.perf_counter()
    seed = source_seed(filter_class) if seed is None else seed
    parts = draw_part_inputs(seed)
    scenarios = draw_scenarios(seed) if "whole" in stages else []
    answers = collect_in_process(filter_class, parts, scenarios, list(stages))
    problem = loading_problem(answers, filter_class.__name__)
    if problem:
        raise NotGradableError(problem)
    copies = copied_parts(class_source(filter_class))
    report = build_report(str(filter_class.name), seed, parts, scenarios, answers, References(), stages, copies)
    report = finish(report)
    report.seconds = time.perf_counter() - started
    return report


def finish(report: Report) -> Report:
    """Name the failing parts in the whole filter's hint (they are why it fails)."""
    failed = [r.part for r in report.rows if not r.passed and r.part != WHOLE]
    whole = next((r for r in report.rows if r.part == WHOLE), None)
    if whole and not whole.passed and failed and whole.hint.startswith(("the parts pass alone", "fix the error")):
        whole.hint = f"fix {', '.join(failed)} first: the whole filter runs with every part"
    return report


def source_seed(thing: Any) -> int:
    """The seed of a class or function without a file of its own: from its source text (a notebook
    cell's too), or 0."""
    try:
        return default_seed(inspect.getsource(thing).encode())
    except (OSError, TypeError):
        return 0


def progress(filter_class: type) -> str:
    """Which parts are still to write, and the checks of those written (what `python my_filter.py`
    prints: a self-check in the student's process)."""
    report = check(filter_class, stages=PARTS)
    todo = [row.part for row in report.rows if row.not_written]
    lines = [f"{filter_class.name}: " + (f"still to write: {', '.join(todo)}" if todo else "all four parts written")]
    written = [row for row in report.rows if not row.not_written]
    if written:
        lines.append(format_rows(written))
    if not todo:
        lines.append(f"Grade the whole filter against the exact posterior: {check_command(filter_class)}")
    return "\n".join(lines)


def check_command(filter_class: type) -> str:
    """The command that grades `filter_class`, to paste back: `mazelab exercise check my_filter.py`
    (with the prefix the program was started with, and `:Class` unless the class is MyFilter)."""
    try:
        source = Path(inspect.getsourcefile(filter_class) or "")
    except TypeError:  # a class defined in a notebook cell or at the prompt has no file
        source = Path()
    if not source.name:
        return f"{command_prefix()} exercise check FILE"
    shown = source.resolve()
    with contextlib.suppress(ValueError):  # outside the folder you are in: the whole path
        shown = shown.relative_to(Path.cwd().resolve())
    spec = str(shown) if filter_class.__name__ == "MyFilter" else f"{shown}:{filter_class.__name__}"
    return f"{command_prefix()} exercise check {shlex.quote(spec)}"


__all__ = [
    "STAGES",
    "Answers",
    "NotGradableError",
    "Report",
    "build_report",
    "check",
    "check_command",
    "check_file",
    "collect_in_process",
    "collect_isolated",
    "finish",
    "progress",
    "source_seed",
]
