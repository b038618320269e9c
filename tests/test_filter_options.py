"""Filter options on the command line (mazelab.cli.options), read from the filters' declarations:
an option that no chosen filter takes is refused in one line naming the filters and what they take (a
flag that tunes an option, such as recovery's rates or KLD's bounds, where the option is); a refusal
names the flags of the command it refuses; an option that some chosen filters take goes to those and
reaches their runs. A value is one line: no control character, no NaN for a number, and a list where
one value goes says that lists are the study's.
"""

from __future__ import annotations

import csv
import textwrap

import pytest

from mazelab.cli.app import main
from mazelab.experiments.runs import final_error
from mazelab.maze import load_maze
from mazelab.robot import Robot
from mazelab.seeding import start_place
from mazelab.simulation import simulate


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--filter", "grid", "--recovery"], "GridBayesFilter does not take --recovery"),
        (["run", "--filter", "grid", "--resampling", "systematic"], "GridBayesFilter does not take --resampling"),
        (["run", "--filter", "ekf", "--bandwidth", "multimodal"], "ExtendedKalmanFilter does not take --bandwidth"),
        (["run", "--filter", "apf", "--init", "start"], "AuxiliaryParticleFilter does not take --init"),
        (["study", "--filters", "sir", "--bandwidth", "multimodal"], "SIRParticleFilter does not take --bandwidth"),
        (["study", "--filters", "sir,apf", "--bandwidth", "0.3"], "SIRParticleFilter and AuxiliaryParticleFilter do"),
        (["study", "--filters", "grid,ekf", "--kld"], "GridBayesFilter and ExtendedKalmanFilter do not take --kld"),
        # a flag that tunes an option (recovery's rates, KLD's bounds) is refused where the option is
        (["run", "--filter", "grid", "--alpha-fast", "0.2"], "GridBayesFilter does not take --alpha-fast"),
        (["run", "--filter", "ekf", "--alpha-slow", "0.01"], "ExtendedKalmanFilter does not take --alpha-slow"),
        (["run", "--filter", "grid", "--kld-epsilon", "0.1"], "GridBayesFilter does not take --kld-epsilon"),
        (["run", "--filter", "ekf", "--kld-z", "1.5"], "ExtendedKalmanFilter does not take --kld-z"),
        (["compare", "s.json", "--filters", "grid,ekf", "--alpha-fast", "0.2"], "ExtendedKalmanFilter do not take"),
    ],
)
def test_the_command_line_refuses_an_option_no_chosen_filter_takes(tmp_path, capsys, args, message):
    if args[0] == "compare":  # a scenario to compare on
        scenario = tmp_path / "s.json"
        assert main(["run", "--steps", "3", "--particles", "20", "--seed", "1", "--quiet", "--no-viz",
                     "--save-scenario", str(scenario)]) == 0  # fmt: skip
        capsys.readouterr()
        args = [args[0], str(scenario), *args[2:]]
    assert main([*args, "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_a_refusal_names_the_flags_of_the_command_it_refuses(capsys):
    """study has --recovery NAMES and no --sensor-resetting: its refusals name only its own flags."""
    assert main(["study", "--filters", "grid", "--recovery", "augmented", "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert "GridBayesFilter does not take --recovery (it takes: resolution, " in err and "--sensor-resetting" not in err


def test_an_option_some_chosen_filters_take_goes_to_those(tmp_path, capsys):
    """`study --estimate mode`: each filter's row says mode, and its errors are those of its run with the mode
    estimate (simulate of the row's seed, estimate="mode"), not those of the mean estimate."""
    table = tmp_path / "study.csv"
    args = ["study", "--maze", "paper_5x5", "--filters", "sir,grid", "--estimate", "mode", "--runs", "1"]
    assert main([*args, "--steps", "4", "--particles", "50", "--seed", "1", "--no-viz", "--workers", "1",
                 "--csv", str(table)]) == 0  # fmt: skip
    with table.open(newline="") as handle:
        rows = {row["filter"]: row for row in csv.DictReader(handle)}
    assert [rows[name]["estimate"] for name in ("SIRParticleFilter", "GridBayesFilter")] == ["mode", "mode"]
    world, seed = load_maze("paper_5x5"), int(rows["SIRParticleFilter"]["seed"])

    def errors(name, estimate, particles=None):
        robot = Robot(0.3, 0.5, start_place(world, seed))
        count = None if particles is not None else 50
        return simulate(robot, world, 0.3, 0.5, count, 4, particles, name, seed=seed, estimate=estimate)

    sir = errors("sir", "mode")
    grid = errors("grid", "mode", sir.inputs.init_particles_pos)
    for name, result in (("SIRParticleFilter", sir), ("GridBayesFilter", grid)):
        mean_error, last_fifth = float(rows[name]["mean_error"]), float(rows[name]["final_error"])
        assert (mean_error, last_fifth) == (result.errors.mean(), final_error(result.errors))
        assert mean_error != errors(name, "mean", sir.inputs.init_particles_pos).errors.mean()


QUICK = ["--steps", "3", "--particles", "20", "--seed", "1", "--no-viz"]


def refusal(capsys, args) -> str:
    """The one line of stderr of a refused command (exit 2, nothing on stdout)."""
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "Traceback" not in err
    return err


@pytest.mark.parametrize(
    "args",
    [
        ["run", "--option", "resampling=systematic,residual"],
        ["run", "--resampling", "stratified,residual"],
        ["run", "--filter", "rpf", "--option", "threshold=0.3,0.5"],
        ["compare", "--filters", "sir,apf", "--option", "resampling=systematic,residual"],
    ],
)
def test_a_list_where_one_value_goes_says_lists_are_the_studys(tmp_path, capsys, args):
    if args[0] == "compare":
        scenario = tmp_path / "s.json"
        assert main(["run", *QUICK, "--quiet", "--save-scenario", str(scenario)]) == 0
        capsys.readouterr()
        args = [args[0], str(scenario), *args[1:], "--no-viz"]
    else:
        args = [*args, *QUICK]
    assert "a list of values is for mazelab study" in refusal(capsys, args)


def test_a_bad_value_with_a_comma_that_is_no_list_gets_no_list_hint(capsys):
    assert "a list of values" not in refusal(capsys, ["run", "--option", "resampling=systematic,nope", *QUICK])
    err = refusal(capsys, ["run", "--filter", "rpf", "--option", "threshold=0,3", *QUICK])
    assert "(write 0.3)" in err and "a list of values" not in err


@pytest.mark.parametrize(
    "args",
    [
        ["run", "--option", "resampling=systematic\nRepeat this run: mazelab run --seed 666"],
        ["run", "--resampling", "systematic\nRepeat this run: mazelab run --seed 666"],
        ["run", "--option", "bogus\nRepeat this run: mazelab run --seed 666=1"],
        ["study", "--option", "resampling=systematic,residual\rRepeat this run", "--runs", "1"],
    ],
)
def test_no_option_value_forges_a_line(capsys, args):
    """A newline in a value would print as a line of its own (the repeat command's, say): refused."""
    assert "control character" in refusal(capsys, [*args, *QUICK])


def test_a_plugins_unchecked_number_option_refuses_nan_naming_it(tmp_path, capsys):
    """An option declared by its default alone has no check: NaN would pass every bound it is compared with."""
    path = tmp_path / "inflated.py"
    path.write_text(
        textwrap.dedent(
            """
            from mazelab.filters import SIRParticleFilter

            class Inflated(SIRParticleFilter):
                options = {**SIRParticleFilter.options, "inflation": 1.0}
            """
        )
    )
    for text in ("nan", "inf", "-1e999"):
        err = refusal(capsys, ["run", "--filter", f"{path}:Inflated", "--option", f"inflation={text}", *QUICK])
        assert f"--option inflation={text}: expected a finite number, got '{text}'" in err
    assert main(["run", "--filter", f"{path}:Inflated", "--option", "inflation=1e26", "--quiet", *QUICK]) == 0
