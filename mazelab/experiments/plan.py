"""A study's plan: its mazes, settings, filters, runs and seed, checked once, whether it comes from the
command line (`mazelab study`) or from Python (`mazelab.study`); its parameters as the record keeps
them, and the lines that describe it."""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mazelab import maze_generator
from mazelab.checks import check_particles, check_sigma_within, check_steps, check_study
from mazelab.declaration import scoped, to_plain_json
from mazelab.experiments.runs import filter_key, parse_filters
from mazelab.experiments.study import (
    BASE_PARAMETERS,
    MODEL_PARAMETERS,
    REFERENCE,
    MazeChoice,
    RunTask,
    StudySetting,
    declared_option,
    file_mazes,
    option_columns,
    options_per_filter,
    study_parameters,
    study_settings,
    study_tasks,
    varied_parameters,
)
from mazelab.experiments.summary import CSV_COLUMNS, describe_setting, describe_varied
from mazelab.grid_filter import check_grid_memory
from mazelab.maze import DEFAULT_MAZE, MAZES_DIR, find_maze, load_maze
from mazelab.maze_generator import DEFAULT_WALL_SHARE
from mazelab.registry import PluginCode, filter_entry, plugin_codes, resolve_filter
from mazelab.regularisation import check_bandwidth
from mazelab.seeding import new_seed


def study_mazes(
    files: Sequence[str] | None,
    sizes: Sequence[str] | None = None,
    stations: Sequence[int] | None = None,
    wall_shares: Sequence[float] | None = None,
) -> list[MazeChoice]:
    """The study's mazes: the files (or shipped names), then every generated size x station-block
    count x wall share; the default maze if none is given."""
    mazes = file_mazes([str(find_maze(name)) for name in files], load_maze) if files else []
    if sizes or stations or wall_shares:
        for rows, columns in (maze_generator.parse_size(s) for s in (sizes or ["10x10"])):
            counts = list(stations) if stations else [maze_generator.default_station_count(rows, columns)]
            for count, share in itertools.product(counts, wall_shares or [DEFAULT_WALL_SHARE]):
                maze_generator.check_generation(rows, columns, count, share)  # --stations 0: refused up front
                mazes.append(MazeChoice.generated(rows, columns, count, share))
    return mazes or file_mazes([str(find_maze(DEFAULT_MAZE))], load_maze)


def maze_description(choice: MazeChoice) -> dict[str, Any]:
    """A maze as the record lists it: a file's path (a shipped maze's as mazes/NAME.txt, the project's
    own; another file's as given, relative to the record's working folder) and sha256, or what
    generates it."""
    if choice.grid is not None:
        return {
            "label": choice.label,
            "file": shipped_path(choice.path),
            "shipped": choice.path is not None and is_shipped_maze(choice.path),
            "sha256": choice.sha256,
            "rows": len(choice.grid),
            "columns": len(choice.grid[0]),
            "station_blocks": sum(row.count(2) for row in choice.grid),
        }
    assert choice.size is not None
    return {
        "label": choice.label,
        "generated": f"{choice.size[0]}x{choice.size[1]}",
        "station_blocks": choice.stations,
        "wall_share": choice.wall_share,
        "note": "a new maze per run, from the run's maze_seed (mazelab maze generate --seed); each run's "
        "maze_sha256 in the CSV is the sha256 of its grid as maze text (Maze.to_text())",
    }


def is_shipped_maze(path: str | Path) -> bool:
    """Whether a maze file is one of the project's own (in mazes/)."""
    return Path(path).resolve().parent == MAZES_DIR.resolve()


def shipped_path(path: str | None) -> str | None:
    """A maze file's path for a record: mazes/NAME.txt for a shipped one (no machine's folder in it)."""
    if path is None or not is_shipped_maze(path):
        return path
    return f"mazes/{Path(path).name}"


@dataclass
class StudyPlan:
    """Everything that fixes a study's rows."""

    settings: list[StudySetting]
    filters: list[Any]  # filter names (or classes, from Python)
    runs: int
    steps: int
    seed: int
    kidnap_at: int | None = None
    kld: bool = False
    traces: bool = False
    reference: str | None = None  # "grid": every row gets distance_to_exact (`study --reference grid`)
    plugins: tuple[PluginCode, ...] = ()  # the plug-ins' code, read once: every run carries it
    call: dict[str, Any] | None = None  # the Python values that made it (mazelab.study_plan), as data

    @property
    def option_columns(self) -> list[str]:
        """The options the study's filters declare (`study.option_columns`): a CSV column each."""
        return list(option_columns(self.filters))

    @property
    def columns(self) -> list[str]:
        """The study CSV's columns: CSV_COLUMNS, then one per option its filters declare."""
        return [*CSV_COLUMNS, *self.option_columns]

    @property
    def varied(self) -> list[str]:
        return varied_parameters(self.settings)

    def tasks(self) -> list[RunTask]:
        """Every run of the study, each with the filters its setting runs."""
        return study_tasks(
            self.settings,
            self.filters,
            self.runs,
            self.steps,
            self.seed,
            kidnap_at=self.kidnap_at,
            traces=self.traces,
            reference=self.reference,
            plugins=self.plugins,
        )

    def parameters(self) -> dict[str, Any]:
        """The study's parameters as parsed (what the record keeps and --resume compares)."""

        def values(parameter: str) -> list[Any]:
            return list(dict.fromkeys(s.value(parameter) for s in self.settings))

        others = study_parameters(self.settings)[len(BASE_PARAMETERS) :]
        return {
            "filters": [resolve_filter(f).name for f in self.filters],
            "mazes": [maze_description(m) for m in dict.fromkeys(s.maze for s in self.settings)],
            **{p: values(p) for p in MODEL_PARAMETERS},
            "options": {p: [to_plain_json(v) for v in values(p)] for p in others},
            "runs": self.runs,
            "steps": self.steps,
            "root_seed": self.seed,
            "kidnap_at": self.kidnap_at,
            "kld": self.kld,
            "reference": self.reference,  # "grid", or None: no distance to the exact posterior
            **({"plugins": [plugin_description(code) for code in self.plugins]} if self.plugins else {}),
        }

    def header(self, where: str, backend: str | None = None) -> str:
        """The study's first lines: its size, seed, workers and backend; the fixed parameters; the varied
        ones with all their values."""
        runs = len(self.tasks()) // max(1, self.runs)
        skipped = len(self.settings) - runs
        note = f" ({skipped} setting(s) run no filter)" if skipped else ""
        on = f", {backend} backend" if backend else ""
        lines = [
            f"Study: {len(self.settings)} setting(s){note} x {self.runs} runs x {len(self.filters)} filters, "
            f"seed {self.seed}, {where}{on}",
            "fixed: " + describe_setting(self.settings[0], self.steps, self.runs, self.kidnap_at, self.varied),
        ]
        if self.varied:
            lines.append(describe_varied(self.settings, self.varied) + " (each filter once per value it takes)")
        if self.reference:
            lines.append("reference: the exact grid filter, once per run's scenario (distance_to_exact)")
        return "\n".join(lines)


def plugin_description(code: PluginCode) -> dict[str, str]:
    """A plug-in as the record lists it: its filter's name, its file (relative to the working folder
    when inside it), its class and the sha256 of the file's bytes the rows were made with."""
    try:
        shown = str(code.path.relative_to(Path.cwd()))
    except ValueError:
        shown = str(code.path)
    return {"filter": resolve_filter(code.spec).name, "file": shown, "class": code.class_name, "sha256": code.sha256}


def plan_study(
    mazes: Sequence[MazeChoice], filters: str | Sequence[Any], *, sigma: Sequence[float], delta: Sequence[float],
    particles: Sequence[int], options: Mapping[str, Sequence[Any]] | None = None, runs: int = 30, steps: int = 200,
    seed: int | None = None, kidnap_at: int | None = None, kld: bool = False, traces: bool = False,
    reference: str | None = None, spelled: Mapping[str, str] | None = None,
) -> StudyPlan:  # fmt: skip
    """Check and combine a study's values into its plan (a new root seed if none is given).

    `options` are the filter options the study sets, by name, each a list of values (a plug-in's
    included; `kld` is a spelling of {"kld": [True]}). An option that no filter of the study takes,
    given a value other than its default, is refused in one line (naming it as `spelled` says: the
    command line's flag), and one given only its default is left out (no filter runs it); every value,
    for every filter that takes it, is checked by its declaration up front."""
    names = parse_filters(filters) if isinstance(filters, str) else _filter_list(filters)
    classes = [resolve_filter(name) for name in names]
    given = {name: list(values) for name, values in (options or {}).items()}
    if kld:
        given["kld"] = [True]
    for name, values in given.items():
        if not values:
            raise ValueError(f"option {name} has no values")
    checked = {name: None if all_default(name, values) else values for name, values in given.items()}
    options_per_filter(names, checked, spelled)
    declared = set(option_columns(classes))
    given = {name: values for name, values in given.items() if scoped(name)[1] in declared}
    check_steps(steps)  # each run's limits, up front rather than in every worker
    check_particles(max(particles))
    settings = study_settings(mazes, sigma, delta, particles, given)
    check_study(len(settings) * runs, len(names))
    check_study_numbers(settings, reference)
    check_filter_options(settings, names)
    seed = new_seed() if seed is None else seed
    kld = given.get("kld") == [True]  # the table's mean N column
    plan = StudyPlan(settings, names, runs, steps, seed, kidnap_at, kld, traces, reference, plugin_codes(names))
    plan.tasks()  # checks runs, steps and kidnap_at
    return plan


def all_default(name: str, values: Sequence[Any]) -> bool:
    """Whether every value given to an option is its declared default (then no filter needs to take it)."""
    option = declared_option(name)
    try:
        return option is not None and all(option.validate(v) == option.default for v in values)
    except ValueError:  # a bad value: refused below, by the declaration of a filter that takes it
        return False


def check_filter_options(settings: Sequence[StudySetting], names: Sequence[Any]) -> None:
    """Every filter's options in every setting, checked by its declaration as its constructor will
    check them (values and combinations), before any run starts."""
    seen: set[tuple[Any, ...]] = set()
    for setting in settings:
        for name in names:
            given = setting.filter_options(name)
            entry = filter_entry(name)
            key = (entry.name, repr(sorted(given.items())))
            if key not in seen:
                seen.add(key)
                entry.options.resolve(given, entry.name)


def check_study_numbers(settings: Sequence[Any], reference: str | None = None) -> None:
    """Each setting's sigma, and a numeric kernel bandwidth if it sets one, within the ranges of its maze
    (mazelab.checks); with --reference, only "grid", whose cells must fit in memory on every maze (its
    constructor's own check, for each maze's size); before any run starts."""
    if reference is not None and reference != REFERENCE:
        raise ValueError(f"--reference {reference}: the reference is the exact grid filter, --reference {REFERENCE}")
    for setting in settings:
        maze = setting.maze
        rows, columns = maze.size if maze.grid is None else (len(maze.grid), len(maze.grid[0]))
        check_sigma_within(setting.sigma, columns, rows)
        if setting.value("bandwidth") is not None:
            check_bandwidth(setting.value("bandwidth"))
        if reference is not None:
            check_grid_memory(columns, rows)


def _filter_list(filters: Sequence[Any]) -> list[Any]:
    """Names resolved to the registry's, classes kept (a student's own filter), without repeats."""
    chosen = [f if isinstance(f, type) else filter_key(f) for f in filters]
    if not chosen:
        raise ValueError("filters is empty; give e.g. ['sir', 'apf', 'rpf']")
    return list(dict.fromkeys(chosen))
