"""Print the README's two commands for a fresh machine, the main job then the tests, one a line.

`.ci/run` runs what this prints, so that CI and the README cannot drift apart. The commands are the
one-line ``bash`` blocks of the README's section "On a fresh machine": the first is the main job,
the second the tests. Anything else there (a third block, a block of several lines) is an error, so a
change of the README's layout is noticed here rather than silently running something else.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path


def readme_commands(readme: str) -> tuple[str, str]:
    """``(main job, tests)``: the two ``bash`` blocks of the section "On a fresh machine"."""
    section = re.search(r"^## On a fresh machine\n(.*?)(?=^## )", readme, flags=re.M | re.S)
    if section is None:
        raise SystemExit("readme_commands: README.md has no section '## On a fresh machine'")
    blocks = [b.strip() for b in re.findall(r"^```bash\n(.*?)^```", section.group(1), flags=re.M | re.S)]
    if len(blocks) != 2 or any("\n" in b for b in blocks):
        raise SystemExit(f"readme_commands: want two one-line bash blocks in 'On a fresh machine', got {blocks!r}")
    main, tests = blocks
    if "pytest" not in tests or "pytest" in main:
        raise SystemExit(f"readme_commands: the second block must run the tests, the first not: {blocks!r}")
    return main, tests


if __name__ == "__main__":
    root = Path(__file__).resolve().parents[1]
    print("\n".join(readme_commands((root / "README.md").read_text(encoding="utf-8"))))
    sys.exit(0)
