"""The package's layout is the formatter's: what `wc -l` counts of mazelab/ is code, not hand layout."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HAND_LAYOUT = re.compile(r"#\s*fmt:\s*(skip|off)\b")


def test_no_hand_layout_in_the_package_or_its_faces():
    """ruff formats every line of the package and the three faces (no `# fmt: skip` or `# fmt: off`):
    the line count the proportion issue measures is then the code's, and each call reads one way."""
    files = [
        *sorted((ROOT / "mazelab").rglob("*.py")),
        *(ROOT / name for name in ("main.py", "particle_filter.py", "draw.py")),
    ]
    hand = [
        f"{path.relative_to(ROOT)}:{number}"
        for path in files
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if HAND_LAYOUT.search(line)
    ]
    assert not hand, f"hand layout (ruff would format these lines): {', '.join(hand[:10])}"
