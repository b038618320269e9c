"""A study's output files on the command line (`mazelab study`): checked before any work
(`StudyOutputs`), and, with --resume, the record and rows of the study to go on with: its parameters,
its plug-ins' code and its rows checked against the plan (`resumed`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mazelab.cli.options import UserError, check_output_path, check_outputs
from mazelab.cli.outputs import check_one_file_each
from mazelab.experiments.plan import StudyPlan
from mazelab.experiments.record import differences, record_path
from mazelab.experiments.resume import (
    RESUME_IGNORES,
    check_rows_of_study,
    missing_tasks,
    read_study_csv,
    read_study_record,
)
from mazelab.experiments.rowlog import check_left_over, check_partial_name, partial_path
from mazelab.experiments.study import RunRecord, RunTask
from mazelab.experiments.summary import summary_path
from mazelab.experiments.traces import check_trace_path, check_traces_of_study


@dataclass
class StudyOutputs:
    """The study's output files, checked before any work: the CSV, figure, traces and record, and the
    record of the study to resume (--resume)."""

    csv_path: Path | None
    plot: Path | None
    traces: Path | None
    record_file: Path | None
    recorded: dict[str, Any] | None
    force: bool
    resume: bool
    traces_kept_from: Path | None = None  # --resume --traces: the earlier session's traces, beside its rows
    summary_csv: Path | None = None  # the table as CSV: --summary-csv, or NAME.summary.csv beside --csv

    @classmethod
    def parse(
        cls, csv_path: Path | None, plot: Path | None, traces: Path | None, record: Path | None,
        rrd: Path | None, force: bool, resume: bool, summary_csv: Path | None = None,
    ) -> StudyOutputs:  # fmt: skip
        """Check the outputs (one line for a name that exists without --force, a folder, a device, a
        symlink at a partial file's name, two outputs that are one file), before any work."""
        record_file = (
            record if record is not None else next((record_path(p) for p in (csv_path, plot, traces) if p), None)
        )
        summary_named = "--summary-csv" if summary_csv is not None else "the summary CSV"
        if summary_csv is None and csv_path is not None:
            summary_csv = summary_path(csv_path)
        named = named_outputs(csv_path, plot, traces, record, record_file, rrd)
        check_one_file_each([*named, (summary_named, summary_csv)])
        if csv_path is not None:  # a stopped study's rows: named before its record
            check_left_over(csv_path, force, adopt=resume)
            for path in (record_file, traces):
                if path is not None:
                    check_partial_name(partial_path(path))
        recorded = check_resume(csv_path, record_file) if resume else None
        check_outputs(None if resume else csv_path, plot, force or resume, rrd)  # --resume replaces its own outputs
        for path in (traces, record_file):
            if path is not None and not resume:
                check_output_path(path, force)
        if traces is not None:
            check_trace_path(traces)
        if summary_csv is not None:
            check_output_path(summary_csv, force or resume)
        kept_from = None
        if resume and traces is not None and csv_path is not None:  # the traces that go with the rows resumed
            kept_from = partial_path(traces) if rows_file(csv_path) != csv_path else traces
        return cls(csv_path, plot, traces, record_file, recorded, force, resume, kept_from, summary_csv)


def named_outputs(
    csv_path: Path | None, plot: Path | None, traces: Path | None, record: Path | None, record_file: Path | None,
    rrd: Path | None,
) -> list[tuple[str, Path | None]]:  # fmt: skip
    """The study's output files by what the user calls them, the partial files beside the CSV too."""
    partials = [] if csv_path is None else [("--csv's partial file", partial_path(csv_path))]
    if csv_path is not None and record_file is not None:
        partials.append(("the record's partial file", partial_path(record_file)))
    if csv_path is not None and traces is not None:
        partials.append(("--traces's partial file", partial_path(traces)))
    named = "--record" if record is not None else "the record"
    others = [("--plot", plot), ("--traces", traces), (named, record_file), ("--rrd", rrd)]
    return [("--csv", csv_path), *partials, *others]


def session_of(recorded: dict[str, Any]) -> dict[str, Any]:
    """An earlier session of a resumed study, as its record said."""
    keys = ("command", "started", "ended", "duration_seconds", "status", "runs_finished")
    return {k: recorded.get(k) for k in keys}


def check_resume(csv_path: Path | None, record_file: Path | None) -> dict[str, Any]:
    """The record of the study to resume: the one beside the partial rows a stopped study left
    (NAME.record.json.partial), else the one beside the CSV; one line if there is none, or if it is
    not a study's record (a list for its parameters, a root seed that is text, a pipe)."""
    if csv_path is None or record_file is None:
        raise UserError("--resume needs the study's --csv (its record lies beside it)")
    if not os.path.lexists(csv_path) and not partial_path(csv_path).exists():
        raise UserError(f"--resume: {csv_path} does not exist (nothing to resume; leave out --resume)")
    if rows_file(csv_path) != csv_path and os.path.lexists(partial_path(record_file)):
        record_file = partial_path(record_file)  # the record of the partial rows, not of the old CSV
    try:
        return read_study_record(record_file)
    except ValueError as error:
        raise UserError(f"--resume: {error}") from None


def check_plugin_code(recorded: dict[str, Any], plan: StudyPlan, record_file: Path | None) -> None:
    """--resume keeps rows made by the same code only: a plug-in whose file's sha256 is not the one
    in the record is refused in one line naming the file and both hashes."""
    before = {p.get("filter"): p for p in recorded["parameters"].get("plugins") or [] if isinstance(p, dict)}
    for now in plan.parameters().get("plugins", []):
        old = before.get(now["filter"])
        if old is not None and old.get("sha256") != now["sha256"]:
            raise UserError(
                f"--resume: {now['file']} is not the code that made the rows (sha256 {old.get('sha256')} in "
                f"{record_file}, {now['sha256']} now); restore it, or start the study again with --force"
            )


def resumed(
    plan: StudyPlan, recorded: dict[str, Any], csv_path: Path, traces_kept_from: Path | None = None
) -> tuple[list[RunTask], list[RunRecord]]:
    """The tasks still to run and the rows to keep, after checking the study against its record,
    and each kept row (and kept trace) against the plan: another study's rows are refused. With
    --traces, a run whose traces are not beside its rows (a study killed with kill -9 writes none; the
    traces beside an older CSV are that CSV's) runs again."""
    changed = differences(recorded["parameters"], plan.parameters(), ignore=RESUME_IGNORES)
    if changed:
        raise UserError(f"--resume: the study differs from its record ({changed[0]}); give the same parameters")
    if plan.runs < recorded["parameters"]["runs"]:
        raise UserError(f"--resume: --runs {plan.runs} is fewer than the study's {recorded['parameters']['runs']}")
    rows, tasks = rows_file(csv_path), plan.tasks()
    try:
        records = read_study_csv(rows, expected=plan.columns)  # this study's columns, its options' too
        check_rows_of_study(tasks, records, rows)
        if traces_kept_from is not None:  # a run is kept with its traces only: one without them runs again
            traced = check_traces_of_study(traces_kept_from, tasks)
            records = [r for r in records if (r.setting, r.run) in traced]
        return missing_tasks(tasks, records)
    except ValueError as error:
        raise UserError(str(error)) from None


def rows_file(csv_path: Path | None) -> Path | None:
    """Where a resumed study's finished rows are: the partial file a stopped study left, else the CSV."""
    if csv_path is None:
        return None
    return partial_path(csv_path) if os.path.lexists(partial_path(csv_path)) else csv_path


__all__ = ["StudyOutputs", "check_plugin_code", "check_resume", "resumed", "rows_file", "session_of"]
