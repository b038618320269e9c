"""The files `mazelab exercise new DIR` writes: the student's filter (four parts to write) and a README,
in English or in a language of mazelab.exercise.language (`--lang uk`): each docstring and error text
of my_filter.py and each paragraph of the README looked up whole in the catalogue, the code the same.
my_filter.py keeps its language (`LANGUAGE = "uk"`), so that `python my_filter.py` and `exercise check`
answer in it. The English texts are the files of `templates/`."""

from __future__ import annotations

import ast
import os
from pathlib import Path

from mazelab.atomic import NameTakenError, NotRegularFileError, output_target, write_text_atomically
from mazelab.exercise.language import catalogue_for

FILTER_FILE = "my_filter.py"
README_FILE = "README.md"

TEMPLATES = Path(__file__).resolve().parent / "templates"  # the texts as files (and the bundle's scripts)
FILTER_TEMPLATE = (TEMPLATES / f"{FILTER_FILE}.txt").read_text()
README_TEMPLATE = (TEMPLATES / f"{README_FILE}.txt").read_text()


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
    for path in paths:  # each name refused in one line where mazelab.atomic would not write it
        try:
            output_target(path, force)
        except (NameTakenError, NotRegularFileError) as error:  # "X: it exists; use --force to replace it"
            raise ValueError(str(error).removeprefix("cannot write ")) from None
        except OSError as error:  # e.g. a part of the folder's path is a file
            raise ValueError(f"cannot write {path}: {error.strerror or error}") from None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"cannot make the folder {folder}: {error.strerror or error}") from None
    # The README first: should a write fail, the student's my_filter.py is the one left as it was.
    for path, text in reversed(list(zip(paths, texts, strict=True))):
        write_text_atomically(path, text, replace=force)
    return paths
