"""Write README.md's measured sections from the JSON ``bayes-mr run`` and ``bayes-mr bench`` wrote.

The library never touches README.md; ``make run`` and ``make bench`` call this
script after the command::

    python scripts/update_readme.py run [--out results]
    python scripts/update_readme.py bench [--json results/bench.json]
    python scripts/update_readme.py study NAME [--out results/studies/NAME]

``run`` reads ``OUT/summary.json``, copies the README's figures of that run
into ``figures/`` beside the README (``results/`` is not under version
control) and writes the section between ``<!-- run:start -->`` and
``<!-- run:end -->``; it writes nothing for a run other than the full job on
the packaged record (``--quick``, another budget or record) unless ``--force``.
``bench`` writes the section between ``<!-- bench:start -->`` and
``<!-- bench:end -->`` from the benchmark's JSON. ``study NAME`` copies a
study's ``report.md``, full or ``--quick`` as the README's text says, (its title dropped, its figures
copied into ``figures/`` as ``NAME_FILE.png``) between ``<!-- NAME:start -->``
and ``<!-- NAME:end -->``. The text of each section is
built by :mod:`bayes_mr.run.readme`; the rest of the README is left alone.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from bayes_mr.run.readme import bench_section, readme_figures, run_section

#: The README this script writes (the repository's, beside ``scripts/``).
README = Path(__file__).resolve().parents[1] / "README.md"


def update_section(readme: str | Path, name: str, markdown: str) -> bool:
    """Replace section ``name`` of ``readme`` with ``markdown``.

    Returns False (and changes nothing) when the file or the markers are
    missing. The file is replaced atomically.
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


def copy_run_figures(summary: dict, figure_dir: Path) -> dict[str, str]:
    """Copy the run's README figures into ``figure_dir`` as ``run_NAME.png``; return key → link from the README."""
    figure_dir.mkdir(parents=True, exist_ok=True)
    links = {}
    for key, src in readme_figures(summary).items():
        if Path(src).exists():
            target = figure_dir / f"run_{Path(src).name}"
            shutil.copyfile(src, target)
            links[key] = f"{figure_dir.name}/{target.name}"
    return links


def write_run(out: Path, readme: Path, force: bool = False) -> bool:
    """The run section from ``out/summary.json`` (figures copied beside ``readme``)."""
    summary = json.loads((out / "summary.json").read_text())
    if not summary.get("full_job") and not force:
        print(f"{out / 'summary.json'}: not the full job on the packaged record; README left as it is "
              "(--force to write it anyway)", file=sys.stderr)
        return False
    links = copy_run_figures(summary, readme.parent / "figures")
    return update_section(readme, "run", run_section(summary, out, links))


def write_bench(path: Path, readme: Path) -> bool:
    """The bench section from the benchmark's JSON ``path``."""
    return update_section(readme, "bench", bench_section(json.loads(path.read_text())))


def write_study(name: str, out: Path, readme: Path) -> bool:
    """A study's section from ``out/report.md``, its figures copied beside ``readme``."""
    lines = (out / "report.md").read_text().splitlines()
    body = "\n".join(lines[1:] if lines and lines[0].startswith("# ") else lines)
    figure_dir = readme.parent / "figures"
    figure_dir.mkdir(parents=True, exist_ok=True)
    for png in sorted(out.rglob("*.png")):  # the report's own figures, beside it or in a subfolder
        rel = png.relative_to(out).as_posix()
        target = figure_dir / f"{name}_{png.name}"
        shutil.copyfile(png, target)
        body = body.replace(f"]({rel})", f"]({figure_dir.name}/{target.name})")
    return update_section(readme, name, body)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="section", required=True)
    p = sub.add_parser("run", help="the run section, from OUT/summary.json")
    p.add_argument("--out", default="results", type=Path, help="the run's output folder (default results)")
    p.add_argument("--force", action="store_true", help="write it even for a quick or partial run")
    p.add_argument("--readme", default=README, type=Path, help=argparse.SUPPRESS)
    p = sub.add_parser("bench", help="the bench section, from the benchmark's JSON")
    p.add_argument("--json", default=Path("results/bench.json"), type=Path, help="default results/bench.json")
    p.add_argument("--readme", default=README, type=Path, help=argparse.SUPPRESS)
    p = sub.add_parser("study", help="a study's section, from its report.md")
    p.add_argument("name", help="the study (and the README's section markers)")
    p.add_argument("--out", type=Path, default=None, help="the study's output folder (default results/studies/NAME)")
    p.add_argument("--readme", default=README, type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.section == "run":
        done = write_run(args.out, args.readme, args.force)
    elif args.section == "study":
        done = write_study(args.name, args.out or Path("results/studies") / args.name, args.readme)
    else:
        done = write_bench(args.json, args.readme)
    if done:
        print(f"updated the {args.section} section of {args.readme}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
