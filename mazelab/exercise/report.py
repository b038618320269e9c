"""The check of one submission (docs/exercise.md, "Grading one submission"): its inputs drawn, its
stages run in child processes within one time budget (`check_file`, the grade) or in this process
(`check`, the self-check, which nothing isolates), the grader's own runs of the exact and the SIR
filters beside them (`reference_run`), each row judged here from the values they returned, and the report
as text of at most WIDTH columns. A submission that cannot be checked at all raises
NotGradableError (one line). Every text that reaches a report is `clean` (parts.py).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import io
import queue
import shlex
import textwrap
import threading
import time
from collections.abc import Callable
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mazelab.exercise.child import Message, WireError, encode, messages, serve
from mazelab.exercise.inputs import (
    PartInputs,
    ScenarioInputs,
    default_seed,
    draw_part_inputs,
    draw_scenarios,
    files_seed,
    request,
)
from mazelab.exercise.kit import class_source, copied_parts
from mazelab.exercise.parts import (
    FAIL,
    FIGURE_COLUMNS,
    NOT_OWN,
    NOT_RUN,
    NOT_WRITTEN,
    PASS,
    SHOWN,
    Row,
    clean,
    expectations,
    judge,
)
from mazelab.exercise.sandbox import DEFAULT_BUDGET, ChildRun, companions_of, run_child, sandbox, submission_copy
from mazelab.exercise.student import PARTS, StudentFilter
from mazelab.exercise.template import Catalogue, catalogue_for
from mazelab.experiments.tables import format_table
from mazelab.invocation import command_prefix
from mazelab.registry import split_spec

STAGES = (*PARTS, "whole")
WHOLE = "whole filter"
ROWS = dict(zip(STAGES, (*PARTS, WHOLE), strict=True))  # each stage's row (the parts', then the whole filter's)
COPY_HINT = "write it yourself: a part may not be the lab's reference implementation with its names changed"
RESERVE = 5.0  # seconds of the budget kept for each stage after the one running (a hang leaves time for the rest)
ENDED_HINT = "a part returns its answer: no exit, no endless loop, nothing that kills the process"
TWICE = "answered twice (two processes answering, or a forged answer beside its own): no answer counts"
WIDTH = 100
PART_WIDTH, RESULT_WIDTH = 12, 12  # "whole filter", "not own work" (wider where a language's words are)
GRID_RESOLUTION = 0.05  # the exact filter's cells: fine next to L = 0.2, coarse enough to be quick
HEADINGS = {
    "given": "Checking {name}: inputs from seed {seed} (given)",
    "files": "Checking {name}: inputs from seed {seed} (from the files; --seed {seed} repeats it)",
    "class": "Checking {name}: inputs from seed {seed} (from the class's source)",
    "key": "Checking {name}: inputs from the grader's secret key",
}
FIGURES_INTRO = (
    "The whole filter on each scenario (distance to the exact mean over the second half of the steps; "
    "yours, then the SIR's):"
)


@dataclass
class Submission:
    """One submission: its name (the folder's or the file's), the file to grade, or why there is none."""

    name: str
    file: Path | None
    problem: str | None = None
    own_folder: bool = False  # a subfolder of its own: the Python files beside the file are its too

    def __post_init__(self) -> None:
        self.name = clean(self.name, 200)


@dataclass
class Report:
    """One submission's check: its rows (the parts, then the whole filter), the whole filter's figures
    per scenario, where its inputs came from (`source`: a key of HEADINGS; `seed` None for a key, which
    no report shows), what went wrong beyond the rows, the time it took (and the student's processes'
    share), their prints, the line saying it ran unsandboxed; in a grading, the submission, or the one
    line why it could not be checked."""

    filter_name: str
    seed: int | None
    source: str = "given"
    rows: list[Row] = field(default_factory=list)
    figures: list = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    seconds: float = 0.0
    student_seconds: float = 0.0
    output: str = ""
    note: str = ""
    scheme: str = "systematic"  # the shipped scheme the student's resampler resembles: the whole filter's SIR uses it
    submission: Submission | None = None  # in a grading (mazelab.exercise.grading)
    problem: str | None = None  # why it could not be checked at all (then it has no rows)

    def __post_init__(self) -> None:  # every text that reaches an output is data (clean)
        self.filter_name = clean(self.filter_name, 80)
        self.problem = None if self.problem is None else clean(self.problem)

    @property
    def passed(self) -> bool:
        """Every row passed (exit code 0)."""
        return bool(self.rows) and all(row.passed for row in self.rows)

    def status(self, part: str) -> str | None:
        """A row's status (FAIL for every row where it could not be checked; None: not run)."""
        if self.problem is not None:
            return FAIL
        return next((row.status for row in self.rows if row.part == part), None)


class NotGradableError(ValueError):
    """The submission cannot be checked at all: one line naming the file and why (its Report's `problem`)."""


# -- the grader's own runs ------------------------------------------------------------------------
_memo: dict[tuple, Future] = {}
_memo_lock = threading.Lock()


class Background(Executor):
    """One daemon thread working through what is submitted: a check that ends early does not wait
    for the reference runs it no longer needs (nor count them as threads left running)."""

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        threading.Thread(target=self._work, name="mazelab-references", daemon=True).start()

    def submit(self, function: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        future: Future = Future()
        self._queue.put((future, function, args, kwargs))
        return future

    def _work(self) -> None:
        while True:
            future, function, args, kwargs = self._queue.get()
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(function(*args, **kwargs))
            except BaseException as error:  # the future carries it to whoever waits
                future.set_exception(error)


_background = functools.cache(Background)  # the one made at the first call


def reference_run(scenario: ScenarioInputs, scheme: str | None = None, executor: Executor | None = None) -> Future:
    """The exact grid filter's run of `scenario` (its posterior means), or with a `scheme` the SIR's
    resampling with it: each computed once per process (a memo of futures), on `executor` (default:
    one background thread, made at its first use)."""
    name, options = ("grid", {"resolution": GRID_RESOLUTION}) if scheme is None else ("sir", {"resampling": scheme})
    with _memo_lock:
        future = _memo.get((name, scheme, scenario.key))
        if future is None or (future.done() and (future.cancelled() or future.exception())):
            future = (executor or _background()).submit(ScenarioInputs.replay, scenario, name, **options)
            _memo[(name, scheme, scenario.key)] = future
        return future


# -- collecting the answers ---------------------------------------------------------------------------
@dataclass
class Answers:
    """What the student's processes gave: the loaded class's description, each stage's answer, how a
    process ended in a stage (or why its answer is void), why nothing loaded, what happened after the
    answers, what they printed and how long they took."""

    loaded: dict[str, Any] | None = None
    results: dict[str, Message] = field(default_factory=dict)
    ended: dict[str, str] = field(default_factory=dict)
    problem: str | None = None
    notes: list[str] = field(default_factory=list)
    output: str = ""
    seconds: float = 0.0


def collect_isolated(
    class_name: str | None,
    parts: PartInputs,
    scenarios: list[ScenarioInputs],
    budget: float,
    stages: tuple[str, ...] = STAGES,
    shown: str = "",
    *,
    files: dict[str, bytes],
) -> Answers:
    """Run the stages in child processes, each in the sandbox of the submission's own copy (`files`,
    {name: bytes}: the file, then its helper modules), within `budget` seconds in all: a new child after a
    stage in which one ended, while the budget lasts. Each way a child ends is one branch below."""
    answers, todo, made = Answers(), list(stages), sandbox()
    with submission_copy(files) as run_folder:
        while todo:
            left = budget - answers.seconds
            if left < 1:
                answers.ended.update(dict.fromkeys(todo, f"was not started: the time budget ({budget:g} s) is spent"))
                break
            wanted = request(made.inside(run_folder, next(iter(files))), class_name, todo, parts, scenarios, shown)
            run = run_child(wanted, run_folder, left, made, reserve=min(RESERVE, left / (2 * len(todo))))
            answers.output, answers.seconds = answers.output + run.output, answers.seconds + run.seconds
            if run.loaded is None:  # it ended while the file was imported: every row fails
                answers.problem = f"the student's process {run.ended or 'sent nothing'}"
                break
            answers.loaded = run.loaded
            void = set(todo) if "loaded" in run.twice else run.twice & set(todo)
            answers.ended.update(dict.fromkeys(void, TWICE))
            answers.results.update({s: m for s, m in run.results.items() if s in todo and s not in void})
            if run.ended is None or void == set(todo) or run.loaded.get("error"):
                break
            left_over = [s for s in todo if s not in run.results and s not in void]
            if not left_over:  # every stage answered, then it ended: the values are judged, the ending noted
                answers.notes.append(f"after its answers the student's process {run.ended}")
                break
            stage = run.stage if run.stage in left_over else left_over[0]  # it ended there: a new child goes on
            answers.ended[stage] = run.ended
            todo = [s for s in left_over if s != stage]
    return answers


def collect_in_process(
    filter_class: type, parts: PartInputs, scenarios: list[ScenarioInputs], stages: list[str]
) -> Answers:
    """Run the stages in this process (a self-check): the same work as the child's, each message
    written and read as a child's would be, and recorded as a child's is (ChildRun.take)."""

    def wired(meta: dict, arrays: dict | None = None) -> Message:
        return next(messages(io.BytesIO(encode(meta, arrays))))

    run = ChildRun()
    serve(wired(*request("", None, stages, parts, scenarios)), lambda *sent: run.take(wired(*sent)), filter_class)
    return Answers(run.loaded, run.results)


# -- the rows ----------------------------------------------------------------------------------------
def build_report(
    report: Report,
    parts: PartInputs,
    scenarios: list[ScenarioInputs],
    answers: Answers,
    references: Callable[..., Future],
    stages: tuple[str, ...] = STAGES,
    copies: dict | None = None,
) -> Report:
    """The report's rows from the answers: each stage's row (its values judged by parts.judge), a part that
    is the lab's code (`copies`, mazelab.exercise.kit.copied_parts) marked not own work; what went wrong
    beyond the rows; the failing parts named in the whole filter's hint."""
    report.output, report.student_seconds = answers.output, answers.seconds
    expected = expectations(parts)
    if answers.problem:
        report.problems.append(clean(answers.problem))
        how = answers.problem.removeprefix("the student's process ")
        report.rows = [ended_row(ROWS[s], expected[s], how, answers.output) for s in stages]
        return report
    for stage in stages:  # the process ended in it, no answer came, an answer the grader cannot read, or judged
        label, message = ROWS[stage], answers.results.get(stage)
        failed = functools.partial(Row, label, FAIL, expected[stage])  # (got, hint)
        try:
            if stage in answers.ended:
                row = ended_row(label, expected[stage], answers.ended[stage], answers.output)
            elif message is None:  # it said "done" (or ended) without this stage's answer
                row = failed("no answer came from the student's process", "a part returns its answer")
            else:
                row = judge(stage, parts, scenarios, message, report, references)
        except WireError as error:
            row = failed(f"an answer the grader cannot read ({error})", "return plain arrays")
        if (copies or {}).get(stage) and row.status != NOT_WRITTEN:
            row = Row(row.part, NOT_OWN, row.expected, copies[stage], COPY_HINT)
        report.rows.append(row)
    report.problems += [clean(f"{ROWS[s]}: the student's process {how}") for s, how in answers.ended.items()]
    report.problems += [clean(note) for note in answers.notes]
    report.problems += [f"{r.part}: {r.got}" for r in report.rows if r.status == NOT_OWN]
    failed = [r.part for r in report.rows if not r.passed and r.part != WHOLE]
    whole = next((r for r in report.rows if r.part == WHOLE), None)
    if whole and not whole.passed and failed and whole.hint.startswith(("the parts pass alone", "fix the error")):
        whole.hint = f"fix {', '.join(failed)} first: the whole filter runs with every part"
    return report


def ended_row(part: str, expected: str, ended: str, output: str) -> Row:
    """The row of the stage in which the student's process ended: how, and its last printed line."""
    last = next((line.strip() for line in reversed(output.splitlines()) if line.strip()), "")
    got = f"the student's process {ended}" + (f"; its last line: {last[:200]}" if last else "")
    return Row(part, FAIL, expected, got, ENDED_HINT)


# -- the checks ----------------------------------------------------------------------------------------
def check_file(
    spec: str,
    *,
    seed: int | None = None,
    key: bytes | None = None,
    timeout: float = DEFAULT_BUDGET,
    references: Executor | None = None,
    stages: tuple[str, ...] = STAGES,
    companions: bool = True,
) -> Report:
    """Grade `path/to/file.py[:Class]` in child processes (the given stages: every part and the whole
    filter by default) within `timeout` seconds in all, the Python files beside it copied with it
    unless `companions` is False (a file directly in a class folder: the others are other students');
    its inputs from `seed`, else from the grader's secret `key` and the files, else from the files
    alone. NotGradableError when it cannot be checked."""
    path, class_name = split_spec(spec)
    shown = clean(f"{path}:{class_name}" if class_name else str(path))
    if not path.is_file():
        raise NotGradableError(f"{shown}: no such file {path}" + ("" if path.exists() else " (check the path)"))
    if path.resolve().suffix != ".py":
        raise NotGradableError(f"{shown}: a link to {path.resolve()}, not a Python file")
    files = {p.name: p.read_bytes() for p in [path, *(companions_of(path) if companions else [])]}  # read once
    source = "given" if seed is not None else "key" if key else "files"
    seed = files_seed(files, key or None) if seed is None else seed
    report = Report(class_name or path.stem, None if source == "key" else seed, source, note=sandbox().note)
    collect = functools.partial(collect_isolated, class_name, budget=timeout, stages=stages, shown=shown, files=files)
    sources = {name: data.decode(errors="replace") for name, data in files.items()}
    return _check(report, seed, stages, collect, sources, references)


def check(filter_class: type, *, seed: int | None = None, stages: tuple[str, ...] = STAGES) -> Report:
    """Check a class in this process (a self-check: nothing isolates it), the given stages (every
    part and the whole filter by default); the seed defaults to one from the class's source, or 0."""
    seed = source_seed(filter_class) if seed is None else seed
    collect = functools.partial(collect_in_process, filter_class, stages=list(stages))
    sources = {"class.py": class_source(filter_class)}
    return _check(Report(filter_class.__name__, seed, "class"), seed, stages, collect, sources)


def _check(
    report: Report,
    seed: int,
    stages: tuple[str, ...],
    collect: Callable[[PartInputs, list[ScenarioInputs]], Answers],
    sources: dict[str, str],
    references: Executor | None = None,
) -> Report:
    """The check both ways: the seed's inputs, the exact runs started while the student's code works,
    its answers collected, the report built (the class named as the student's process says)."""
    started = time.perf_counter()
    parts = draw_part_inputs(seed)
    scenarios = draw_scenarios(seed) if "whole" in stages else []
    runs = functools.partial(reference_run, executor=references)
    for scenario in scenarios:
        runs(scenario)
    answers = collect(parts, scenarios)
    loaded = answers.loaded or {}
    if loaded.get("error"):  # it does not import, has no such class, or the class is not a StudentFilter
        raise NotGradableError(loaded["error"])
    report.filter_name = clean(loaded.get("name") or report.filter_name, 80)
    build_report(report, parts, scenarios, answers, runs, stages, copied_parts(sources))
    report.seconds = time.perf_counter() - started
    return report


def source_seed(thing: Any) -> int:
    """The seed of a class or function without a file of its own: from its source text (a notebook
    cell's too), or 0."""
    try:
        return default_seed(inspect.getsource(thing).encode())
    except (OSError, TypeError):
        return 0


# -- the report as text ---------------------------------------------------------------------------------
def _wrapped(text: str, first: str, indent: int, width: int) -> list[str]:
    """`first` then `text`, wrapped to `width`, continuation lines indented by `indent`."""
    lines = textwrap.wrap(text, width - indent, break_long_words=True, break_on_hyphens=False) or [""]
    return [first + lines[0], *(" " * indent + line for line in lines[1:])]


def format_rows(rows: list[Row], width: int = WIDTH, catalogue: Catalogue | None = None) -> str:
    """The rows: part, result, what came; under a row that did not pass, "expected:" and "hint:" (in
    the catalogue's language: English by default)."""
    words = catalogue or Catalogue()
    _ = words.gettext
    part_width = max(PART_WIDTH, *(len(_(row.part)) for row in rows))
    result_width = max(RESULT_WIDTH, *(len(_(SHOWN.get(s, s))) for s in (PASS, FAIL, NOT_WRITTEN, NOT_RUN, NOT_OWN)))
    indent = part_width + result_width + 4
    lines = [f"{_('part'):<{part_width}}  {_('result'):<{result_width}}  {_('got')}", "-" * min(width, 80)]
    for row in rows:
        first = f"{_(row.part):<{part_width}}  {_(SHOWN.get(row.status, row.status)):<{result_width}}  "
        lines += _wrapped(words.translate(row.got), first, indent, width)
        if row.status not in (PASS, NOT_WRITTEN, NOT_RUN):
            lines += _wrapped(_("expected: ") + words.translate(row.expected), " " * indent, indent, width)
        if not row.passed and row.hint:
            lines += _wrapped(_("hint: ") + words.translate(row.hint), " " * indent, indent, width)
    return words.numbers("\n".join(lines))


def format_report(report: Report, width: int = WIDTH, catalogue: Catalogue | None = None) -> str:
    """The whole report: the heading, the rows, the figures per scenario, and the verdict."""
    words = catalogue or Catalogue()
    _ = words.gettext
    heading = _(HEADINGS[report.source]).format(name=report.filter_name, seed=report.seed)
    lines = [*_wrapped(heading, "", 0, width), "", format_rows(report.rows, width, words)]
    if report.note:
        lines[1:1] = _wrapped(words.translate(report.note), "", 0, width)
    if report.figures:
        table = [[words.translate(cell(f)) for _heading, cell in FIGURE_COLUMNS] for f in report.figures]
        headers = [_(heading) for heading, _cell in FIGURE_COLUMNS]
        lines += ["", *_wrapped(_(FIGURES_INTRO), "", 0, width), format_table(headers, table)]
    failed = [_(r.part) for r in report.rows if not r.passed]
    lines += ["", _("All checks pass.") if not failed else _("To fix: {parts}.").format(parts=", ".join(failed))]
    return words.numbers("\n".join(lines))


# -- the student's own process (mazelab.exercise.selfcheck) -------------------------------------------------
def check_part(part: str, function: Callable[..., object], lang: str = "en") -> Row:
    """Check one part written as a plain function `part(self, ...)` (a notebook cell), print its row
    (in `lang`: en or uk)."""
    if part not in PARTS:
        raise ValueError(f"unknown part {part!r}; the parts are {', '.join(PARTS)}")
    notebook_filter = type("NotebookFilter", (StudentFilter,), {part: function})
    row = check(notebook_filter, seed=source_seed(function), stages=(part,)).rows[0]
    print(format_rows([row], catalogue=catalogue_for(lang)))
    return row


def check_and_print(filter_class: type, lang: str = "en") -> Report:
    """Check every part and the whole filter, and print the report (the notebook's last check cell),
    in `lang` (en or uk)."""
    report = check(filter_class)
    print(format_report(report, catalogue=catalogue_for(lang)))
    return report


def progress(filter_class: type, lang: str | None = None) -> str:
    """Which parts are still to write, and the checks of those written (what `python my_filter.py`
    prints: a self-check in the student's process), in `lang` (default: the file's LANGUAGE, else the
    locale's)."""
    words = catalogue_for(lang or getattr(inspect.getmodule(filter_class), "LANGUAGE", None))
    report = check(filter_class, stages=PARTS)
    todo = [row.part for row in report.rows if row.status == NOT_WRITTEN]
    left = words.gettext("still to write: {parts}").format(parts=", ".join(todo))
    lines = [f"{filter_class.name}: " + (left if todo else words.gettext("all four parts written"))]
    written = [row for row in report.rows if row.status != NOT_WRITTEN]
    lines += [format_rows(written, catalogue=words)] if written else []
    if not todo:
        command = check_command(filter_class)
        lines.append(
            words.gettext("Grade the whole filter against the exact posterior: {command}").format(command=command)
        )
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
