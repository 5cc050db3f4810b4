#!/usr/bin/env python3
"""Rewrites the "Every source file" list at the end of ARCHITECTURE.md: each Rust file the
repository tracks, with the first sentence of its module documentation (`//!`). Run it after
adding, moving or removing a Rust file:

    python3 scripts/file-index.py          # rewrite the list
    python3 scripts/file-index.py --check  # exit 1 if the list is out of date
"""
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
START = "<!-- file-index: start (scripts/file-index.py writes this list) -->"
END = "<!-- file-index: end -->"


def summary(path: Path) -> str:
    doc = []
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        if line.startswith("//!"):
            text = line[3:].strip()
            if not text and doc:
                break
            if text:
                doc.append(text)
        elif doc or line.strip():
            break
    text = re.sub(r"\[(`[^`]+`)\](\([^)]*\))?", r"\1", " ".join(doc))
    m = re.match(r"(.+?\.)(\s|$)", text)
    first = m.group(1) if m else text
    if len(first) > 140 and ": " in first[:120]:
        first = first[: first.index(": ")] + "."
    return first or "(no module documentation)"


def rust_files() -> list:
    """The Rust files git tracks; without git (or where git refuses the checkout), every .rs
    file outside build output and virtual environments."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "*.rs"], cwd=ROOT, capture_output=True, check=True
        ).stdout
        return sorted(f for f in out.decode("utf-8").split("\0") if f)
    except (OSError, subprocess.CalledProcessError):
        skip = {"target", ".git", ".venv", "node_modules"}
        return sorted(
            str(p.relative_to(ROOT))
            for p in ROOT.rglob("*.rs")
            if not skip.intersection(p.relative_to(ROOT).parts)
        )


def index() -> str:
    return "\n".join(f"- `{f}`: {summary(ROOT / f)}" for f in rust_files())


def main() -> int:
    arch = ROOT / "ARCHITECTURE.md"
    text = arch.read_text(encoding="utf-8")
    block = f"{START}\n{index()}\n{END}"
    if START in text:
        new = re.sub(re.escape(START) + r".*?" + re.escape(END), lambda _: block, text, flags=re.S)
    else:
        new = text.rstrip("\n") + "\n\n## Every source file\n\n" + block + "\n"
    if "--check" in sys.argv[1:]:
        if new != text:
            print("ARCHITECTURE.md's file list is out of date: run python3 scripts/file-index.py")
            return 1
        return 0
    arch.write_text(new, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
