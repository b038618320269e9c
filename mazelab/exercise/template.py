"""The files `mazelab exercise new DIR` writes: the student's filter (four parts to write) and a README,
in English or in a language of mazelab.exercise.language (`--lang uk`): each docstring and error text
of my_filter.py and each paragraph of the README looked up whole in the catalogue, the code the same.
my_filter.py keeps its language (`LANGUAGE = "uk"`), so that `python my_filter.py` and `exercise check`
answer in it."""

from __future__ import annotations

import ast
import os
from pathlib import Path

from mazelab.atomic import NameTakenError, NotRegularFileError, output_target, write_text_atomically
from mazelab.exercise.language import catalogue_for

FILTER_FILE = "my_filter.py"
README_FILE = "README.md"

FILTER_TEMPLATE = '''"""My particle filter: the four parts of Algorithm 4 (SIR) for the maze lab.

Run `python my_filter.py` to see which parts are still to write, and
`mazelab exercise check my_filter.py` to grade them against the exact posterior. LANGUAGE is the
language of their reports (en or uk).
"""

import numpy as np

from mazelab.exercise import OUTSIDE_PENALTY, ROBOT_SPEED, StudentFilter

LANGUAGE = "en"


class MyFilter(StudentFilter):
    """SIR (Arulampalam et al. 2002, Algorithm 4) for the paper's model.

    Available: self.world (world.distance_to_nearest_station(points), world.is_free(x, y)),
    self.sigma (measurement noise std), self.delta (compass error width, radians),
    ROBOT_SPEED (L = 0.2) and OUTSIDE_PENALTY (0.5).
    """

    def predict(self, positions, compass_angle, rng):
        """Algorithm 4, line "Draw x_k^i ~ p(x_k | x_(k-1)^i)": the paper's equation (1).

        Each particle moves ROBOT_SPEED along its own heading th ~ U(th0 - delta/2, th0 + delta/2),
        th0 = compass_angle. positions (N, 2) -> moved positions (N, 2). Draw only from `rng`.
        Walls are not predict's job (weigh penalises particles outside the free area).
        """
        raise NotImplementedError("predict is still to write")

    def weigh(self, positions, z):
        """Algorithm 4, line "Calculate w_k^i = p(z_k | x_k^i)": the paper's equation (3) in logs.

        log N(z; d, sigma^2), d = the distance from each position to its nearest station, plus
        log(OUTSIDE_PENALTY) for positions outside the free area (the paper's refinement 1).
        positions (N, 2) -> log-likelihoods (N,); a constant offset is fine (unnormalised).
        """
        raise NotImplementedError("weigh is still to write")

    def resample(self, weights, rng):
        """Algorithm 4, last line "RESAMPLE" (Algorithm 2, or any unbiased scheme).

        Normalised weights (N,) -> ancestor indices (N,) with E[copies of i] = N * weights[i].
        Draw only from `rng`.
        """
        raise NotImplementedError("resample is still to write")

    def estimate(self, positions, weights):
        """The paper's estimate: the posterior mean sum_i W_i x_i of the weighted particles
        (Algorithm 4's output {x_k^i, w_k^i} summarised; the circle's centre in the viewer).

        positions (N, 2), normalised weights (N,) -> the point estimate (2,).
        """
        raise NotImplementedError("estimate is still to write")


if __name__ == "__main__":
    from mazelab.exercise.report import progress

    print(progress(MyFilter))
'''

README_TEMPLATE = """# Your own particle filter

`my_filter.py` holds `MyFilter`, the SIR filter (Algorithm 4 of Arulampalam et al.) for the maze
lab's model, with four parts for you to write. Each method's docstring names the paper's equation
and the line of Algorithm 4 it implements:

1. `predict(positions, compass_angle, rng)`: the motion model, equation (1).
2. `weigh(positions, z)`: the log-likelihood, equation (3), with the penalty outside the free area.
3. `resample(weights, rng)`: ancestor indices drawn by the weights (Algorithm 2, or any unbiased scheme).
4. `estimate(positions, weights)`: the posterior mean.

`StudentFilter` does the rest (normalising the weights in logs, the effective sample size, the green
circle, restarting from the prior when no particle explains a measurement). Use numpy on whole
arrays (no loops over particles) and draw random numbers only from the `rng` you are given.

- `python my_filter.py` says which parts are still to write and checks those you wrote.
- `mazelab exercise check my_filter.py` grades every part and the whole filter against the exact
  posterior (a row per part: pass or fail, what came, and under a failing row what was expected and a
  hint). Exit code 0 means all pass. It runs your files in a sandbox of their own, on inputs drawn
  from their content (an edit gets new ones; `--seed S` repeats a report) and judges only what your
  code returns. The lab's reference implementation (mazelab.model's functions, mazelab.resampling,
  the shipped filters) is not in that sandbox: each part must be your own code, and one copied from
  the lab's with its names changed is marked "not own work". The reports speak the language of
  `LANGUAGE` in my_filter.py (`--lang en` or `--lang uk` chooses another).
- `mazelab run --filter my_filter.py:MyFilter` runs it in the viewer; `mazelab compare SCENARIO
  --filters sir,my_filter.py:MyFilter` puts it beside the shipped SIR.

Here `python` and `mazelab` stand for the way you start the lab: `uv run --project CLONE python` and
`uv run --project CLONE mazelab` with uv from a folder of your own (CLONE: the lab's folder), plain
`python` and `mazelab` in its activated environment. Once all four parts are written, `python
my_filter.py` prints the grading command written your way, to paste.
"""


def exercise_texts(language: str = "en") -> tuple[str, str]:
    """my_filter.py and README.md in `language`: each string literal of the filter (its docstrings and
    error texts) and each paragraph of the README translated whole; ValueError for an unknown language."""
    words = catalogue_for(language)
    text = FILTER_TEMPLATE.replace('LANGUAGE = "en"', f'LANGUAGE = "{words.language}"')
    for node in ast.walk(ast.parse(FILTER_TEMPLATE)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in words.entries:
            text = text.replace(node.value, words.entries[node.value])
    readme = "\n\n".join(words.gettext(paragraph) for paragraph in README_TEMPLATE.split("\n\n"))
    return text, readme


def write_exercise(folder: Path, force: bool = False, language: str = "en") -> list[Path]:
    """Write my_filter.py and README.md into `folder` (made if missing) through mazelab.atomic: each
    file is the old one or the new whole one, a folder, pipe, device or symlink loop at either name is
    refused, and without `force` so is any name that exists (a symlink too, dangling or not). Both
    names are checked before either file is written (a ValueError of one line); a write that fails
    (a full disk) is a WriteError naming the file, with the old file left whole. Returns the paths."""
    paths, texts = [folder / FILTER_FILE, folder / README_FILE], exercise_texts(language)
    if os.path.lexists(folder) and not folder.is_dir():
        raise ValueError(f"{folder} is not a folder (give a folder to write the exercise into)")
    if folder.is_dir() and not os.access(folder, os.W_OK):
        raise ValueError(f"{folder} is not writable: cannot write the exercise there")
    for path in paths:
        check_exercise_file(path, force)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"cannot make the folder {folder}: {error.strerror or error}") from None
    # The README first: should a write fail, the student's my_filter.py is the one left as it was.
    for path, text in reversed(list(zip(paths, texts, strict=True))):
        write_text_atomically(path, text, replace=force)
    return paths


def check_exercise_file(path: Path, force: bool) -> None:
    """Refuse, in one line, an exercise file's name that mazelab.atomic would not write."""
    try:
        output_target(path, force)
    except (NameTakenError, NotRegularFileError) as error:  # "X: it exists; use --force to replace it"
        raise ValueError(str(error).removeprefix("cannot write ")) from None
    except OSError as error:  # e.g. a part of the folder's path is a file
        raise ValueError(f"cannot write {path}: {error.strerror or error}") from None
