"""Write measured numbers into README.md between markers, so none is typed by hand.

A section is delimited by ``<!-- NAME:start -->`` and ``<!-- NAME:end -->``;
:func:`update_section` replaces what lies between them and leaves the rest
of the file alone.
"""

from __future__ import annotations

from pathlib import Path


def update_section(readme: str | Path, name: str, markdown: str) -> bool:
    """Replace section ``name`` of ``readme`` with ``markdown``.

    Returns False (and changes nothing) when the file or the markers are
    missing, e.g. when the package runs outside its source tree.
    """
    path = Path(readme)
    if not path.is_file():
        return False
    text = path.read_text()
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    i, j = text.find(start), text.find(end)
    if i < 0 or j < i:
        return False
    new = text[: i + len(start)] + "\n" + markdown.strip() + "\n" + text[j:]
    if new != text:
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(new)
        tmp.replace(path)
    return True


def project_readme() -> Path:
    """README.md of the source tree this package runs from (editable install)."""
    return Path(__file__).resolve().parents[1] / "README.md"
