"""The exercise's words: the languages its texts are shown in, and the files it writes from `templates/`.

Languages (docs/exercise.md, "The report in Ukrainian"): gettext catalogues, English by default,
Ukrainian in `locale/uk.po`, read by the small reader below (nothing in it runs); the texts are made in
English where they are computed and translated where they are shown (`Catalogue.translate`, numbers
by `Catalogue.numbers`). Files: `exercise new DIR` writes my_filter.py and a README in a language
(`exercise_texts`); `exercise autograder OUT.zip` writes Gradescope's bundle (docs/exercise.md, "On
Gradescope", says what it holds and how `MAZELAB_AUTOGRADER_ROOT` and `MAZELAB_COMMAND` run it in a
simulated tree)."""

from __future__ import annotations

import ast
import hashlib
import io
import os
import re
import shlex
import stat
import zipfile
from functools import cache
from importlib import metadata
from pathlib import Path

from mazelab import __version__
from mazelab.atomic import NameTakenError, NotRegularFileError, output_target, write_atomically
from mazelab.exercise.kit import PACKAGE_DIR
from mazelab.exercise.sandbox import DEFAULT_BUDGET

FILTER_FILE = "my_filter.py"
README_FILE = "README.md"

TEMPLATES = Path(__file__).resolve().parent / "templates"  # the texts as files (and the bundle's scripts)
FILTER_TEMPLATE = (TEMPLATES / f"{FILTER_FILE}.txt").read_text()
README_TEMPLATE = (TEMPLATES / f"{README_FILE}.txt").read_text()
ROOT = PACKAGE_DIR.parent
LAB_FILES = ("pyproject.toml", "uv.lock", "README.md", "MANIFEST.in", "main.py", "draw.py", "particle_filter.py")
DISTRIBUTION = "maze-particle-filter-lab"
LAB_FOLDERS = {"mazelab": ("*.py", "*.po", "*.txt"), "mazes": ("*.txt",), "model_parameters": ("*.json",)}
SETUP = (TEMPLATES / "setup.sh.txt").read_text()  # str.format fields: version, digest
RUN = (TEMPLATES / "run_autograder.txt").read_text()  # version, timeout, options


LOCALE_DIR = Path(__file__).resolve().parent / "locale"
ENGLISH = "en"
FIELD = re.compile(r"\{(\w+)\}")
MIN_PIECE = 12  # a msgid shorter than this is translated only as a whole text (never inside another)
DECIMAL_COMMA = ("uk",)  # languages that write 0,5 for 0.5


class CatalogueError(ValueError):
    """A .po file the reader cannot read: the file and the line."""


def languages() -> tuple[str, ...]:
    """The languages with a catalogue, English first."""
    return (ENGLISH, *sorted(p.stem for p in LOCALE_DIR.glob("*.po")))


def read_po(path: Path) -> dict[str, str]:
    """The msgid -> msgstr pairs of a .po file (the header's empty msgid and untranslated ones left out)."""
    entries: dict[str, str] = {}
    field, values = None, {"msgid": [], "msgstr": []}

    def flush() -> None:
        msgid, msgstr = "".join(values["msgid"]), "".join(values["msgstr"])
        if msgid and msgstr:
            entries[msgid] = msgstr
        values["msgid"], values["msgstr"] = [], []

    for number, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        keyword, _, rest = line.partition(" ")
        if keyword in ("msgid", "msgstr"):
            if keyword == "msgid" and values["msgstr"]:
                flush()
            field, line = keyword, rest.strip()
        if field is None or not (line.startswith('"') and line.endswith('"') and len(line) >= 2):
            raise CatalogueError(f"{path}, line {number}: not a msgid, a msgstr or a quoted string")
        try:  # its C escapes read as a Python string literal: a literal, never code
            value = ast.literal_eval(line)
        except (ValueError, SyntaxError):
            raise CatalogueError(f"{path}, line {number}: a string the reader cannot read") from None
        if not isinstance(value, str):
            raise CatalogueError(f"{path}, line {number}: not a string")
        values[field].append(value)
    flush()
    return entries


class Catalogue:
    """One language's messages: `gettext` for a whole text, `translate` for a report's composed texts."""

    def __init__(self, language: str = ENGLISH, entries: dict[str, str] | None = None):
        self.language = language
        self.entries = entries or {}
        patterns = [(k, v) for k, v in self.entries.items() if FIELD.search(k)]
        self.patterns = [(_pattern(k), v) for k, v in sorted(patterns, key=lambda kv: -len(kv[0]))]
        pieces = [(k, v) for k, v in self.entries.items() if len(k) >= MIN_PIECE and not FIELD.search(k)]
        self.pieces = sorted(pieces, key=lambda kv: -len(kv[0]))

    def gettext(self, message: str) -> str:
        return self.entries.get(message, message)

    def translate(self, text: str) -> str:
        """`text` translated: whole, else each msgid (with fields or not) found in it."""
        if not self.entries or not text:
            return text
        if text in self.entries:
            return self.entries[text]
        for pattern, translation in self.patterns:
            text = pattern.sub(lambda m, t=translation: t.format(**self._values(m.groupdict())), text)
        for message, translation in self.pieces:
            text = text.replace(message, translation)
        return text

    def numbers(self, text: str) -> str:
        """`text` with its numbers as the language writes them: 0.25, 0.5 -> 0,25; 0,5 in Ukrainian."""
        if self.language not in DECIMAL_COMMA:
            return text
        text = re.sub(r"(\d),(\s+)(?=[-+]?\d)", r"\1;\2", text)
        return re.sub(r"(?<=\d)\.(?=\d)", ",", text)

    def _values(self, values: dict[str, str]) -> dict[str, str]:
        """A pattern's field values, each translated where it is a msgid (a weight vector's kind)."""
        return {name: self.entries.get(value, value) for name, value in values.items()}


def _pattern(message: str) -> re.Pattern[str]:
    """A msgid with `{name}` fields as a pattern matching any value there (within one clause; a field
    at the end takes the clause's rest)."""
    parts, seen, regex = FIELD.split(message), set(), ""
    last = len(parts) - 2 if parts[-1] == "" else -1
    for i, part in enumerate(parts):
        if i % 2 == 0:
            regex += re.escape(part)
        else:  # a field named twice matches the same value twice
            regex += f"(?P={part})" if part in seen else f"(?P<{part}>[^;]+{'' if i == last else '?'})"
            seen.add(part)
    return re.compile(regex)


@cache
def catalogue(language: str) -> Catalogue:
    """The catalogue of `language` (ValueError naming the languages there are)."""
    if language == ENGLISH:
        return Catalogue()
    path = LOCALE_DIR / f"{language}.po"
    if not re.fullmatch(r"[a-z]{2,3}(_[A-Z]{2})?", language) or not path.is_file():
        raise ValueError(f"no catalogue for {language!r} (there are: {', '.join(languages())})")
    return Catalogue(language, read_po(path))


def locale_language() -> str:
    """The locale's language when it has a catalogue, else English."""
    for name in ("LANGUAGE", "LC_ALL", "LC_MESSAGES", "LANG"):
        for value in os.environ.get(name, "").split(":"):
            code = value.split(".")[0].split("_")[0].lower()
            if code and code in languages():
                return code
            if code and code not in ("c", "posix"):
                break
    return ENGLISH


def catalogue_for(language: str | None, file: Path | None = None) -> Catalogue:
    """The catalogue of `language` (a code: en, uk), else of the exercise `file`'s, else the locale's."""
    chosen = language or (file_language(file) if file is not None else None) or locale_language()
    return catalogue(chosen.strip().lower())


def file_language(path: Path) -> str | None:
    """The language an exercise file asks for (its top-level `LANGUAGE = "uk"`), read without running it."""
    try:
        tree = ast.parse(path.read_text(errors="replace"))
    except (OSError, SyntaxError, ValueError):
        return None
    for node in tree.body:
        if isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["LANGUAGE"]:
            value = getattr(node.value, "value", None)
            return value if value in languages() else None
    return None


# -- the files ------------------------------------------------------------------------------------------
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
        write_atomically(path, text, replace=force)
    return paths


class BundleError(ValueError):
    """The bundle cannot be made here: one line saying why."""


def lab_files() -> list[Path]:
    """The lab's files the bundle carries (relative to the repository), sorted."""
    if not (ROOT / "pyproject.toml").is_file():
        raise BundleError(
            f"the bundle is made from the lab's source: pyproject.toml missing in {ROOT} (an install from a clone, "
            "`pip install -e CLONE` or `uv sync`, makes it from there)"
        )
    found = [Path(name) for name in LAB_FILES if (ROOT / name).is_file()]
    for folder, patterns in LAB_FOLDERS.items():
        for pattern in patterns:
            found += [p.relative_to(ROOT) for p in (ROOT / folder).rglob(pattern) if "__pycache__" not in p.parts]
    return sorted(set(found))


def pinned_requirements() -> str:
    """The lab's dependencies at the versions installed here (requirements.txt, where there is no uv.lock)."""
    lines = []
    for requirement in metadata.requires(DISTRIBUTION) or []:
        if "extra ==" not in requirement:
            name = re.match(r"[A-Za-z0-9_.-]+", requirement).group(0)
            lines.append(f"{name}=={metadata.version(name)}")
    return "\n".join(sorted(lines)) + "\n"


def bundle_bytes(key: bytes, lang: str | None = None, timeout: float = DEFAULT_BUDGET) -> bytes:
    """The zip: setup.sh and run_autograder (executable, the instructor's language and time budget baked
    in) and the key at its top, the lab's source under lab/ (setup.sh names its sha256: names and contents)."""
    sources = {name.as_posix(): (ROOT / name).read_bytes() for name in lab_files()}  # read once: digested, zipped
    digest = hashlib.sha256(b"".join(f"{name}\0".encode() + data + b"\0" for name, data in sources.items()))
    options = shlex.join(["--lang", lang] if lang else [])
    texts = {
        "setup.sh": SETUP.format(version=__version__, digest=digest.hexdigest()),
        "run_autograder": RUN.format(version=__version__, timeout=f"{timeout:g}", options=options).replace(" \n", "\n"),
        "grading.key": key.hex() + "\n",
    }
    texts |= {f"lab/{name}": data for name, data in sources.items()}
    if not (ROOT / "uv.lock").is_file():
        texts["lab/requirements.txt"] = pinned_requirements()
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as bundle:
        for name, text in texts.items():
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            mode = 0o755 if name in ("setup.sh", "run_autograder") else 0o600 if name == "grading.key" else 0o644
            info.external_attr = (stat.S_IFREG | mode) << 16
            bundle.writestr(info, text)
    return buffer.getvalue()
