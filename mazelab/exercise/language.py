"""The check report's language (docs/exercise.md, "The report in Ukrainian"): gettext catalogues,
English by default, Ukrainian in `locale/uk.po`, read by the small reader below (nothing in it runs).
The texts are made in English where they are computed (the grader's verdicts) and translated where
they are shown (`Catalogue.translate`), numbers written as the language writes them
(`Catalogue.numbers`). The language: `--lang`, else the exercise file's `LANGUAGE`, else the locale's.
"""

from __future__ import annotations

import ast
import gettext
import os
import re
from functools import cache
from pathlib import Path

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


class Catalogue(gettext.NullTranslations):
    """One language's messages: `gettext` for a whole text, `translate` for a report's composed texts."""

    def __init__(self, language: str = ENGLISH, entries: dict[str, str] | None = None):
        super().__init__()
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
