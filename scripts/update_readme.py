"""Copy a run's JSON into docs/data/ and rewrite docs/results.md and docs/performance.md from docs/data/ alone.

The library never writes these documents; ``make run`` and ``make bench``
call this script after the command::

    python scripts/update_readme.py run [--out results]
    python scripts/update_readme.py bench [--json results/bench.json]
    python scripts/update_readme.py study NAME [--out results/studies/NAME]
    python scripts/update_readme.py all

``run`` copies ``OUT/summary.json`` to ``docs/data/run.json`` and the run's
figures the results show to ``docs/figures/run_FILE.png``; it refuses a run
other than the full job on the packaged record (``--quick``, another budget or
record) unless ``--force``. ``bench`` copies the benchmark's JSON to
``docs/data/bench.json``. ``study NAME`` copies ``OUT/summary.json`` to
``docs/data/NAME.json`` and the study's figures to ``docs/figures/NAME_FILE.png``.
Each then rewrites both documents; ``all`` only rewrites them, from what is
under ``docs/data/`` and ``docs/figures/`` (no run). The text is built by
``scripts/docs_sections.py``; README.md is not touched (it holds no measured
number).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # docs_sections, beside this script

from docs_sections import DOCS, STUDIES, documents, run_figure_name, run_figures, study_figure_name  # noqa: E402


def _copy_json(src: Path, dst: Path) -> dict:
    """Copy JSON ``src`` to ``dst`` (re-indented, so that diffs of docs/data stay readable); return it."""
    data = json.loads(src.read_text())
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_text(json.dumps(data, indent=1, ensure_ascii=False) + "\n")
    return data


def write_documents(docs: Path) -> list[Path]:
    """Rewrite the generated documents under ``docs`` from ``docs/data``; return those that changed."""
    changed = []
    for name, text in documents(docs).items():
        path = docs / name
        if not path.is_file() or path.read_text() != text:
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(text)
            tmp.replace(path)
            changed.append(path)
    return changed


def take_run(out: Path, docs: Path, force: bool = False) -> bool:
    """``out/summary.json`` → ``docs/data/run.json``, the run's figures → ``docs/figures/``."""
    summary = json.loads((out / "summary.json").read_text())
    if not summary.get("full_job") and not force:
        print(f"{out / 'summary.json'}: not the full job on the packaged record; docs/data left as it is "
              "(--force to take it anyway)", file=sys.stderr)
        return False
    figures = docs / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    for old in figures.glob("run_*.png"):  # the figures of the run before, which this run may not have drawn
        old.unlink()
    for src in run_figures(summary).values():
        # a figure path as the run wrote it: relative to where it ran, or inside OUT
        path = Path(src) if Path(src).exists() else out / Path(src).name
        if path.exists():
            shutil.copyfile(path, figures / run_figure_name(src))
    _copy_json(out / "summary.json", docs / "data" / "run.json")
    return True


def take_bench(path: Path, docs: Path) -> bool:
    """The benchmark's JSON ``path`` → ``docs/data/bench.json``."""
    _copy_json(path, docs / "data" / "bench.json")
    return True


def take_study(name: str, out: Path, docs: Path) -> bool:
    """``out/summary.json`` of study ``name`` → ``docs/data/NAME.json``, its figures → ``docs/figures/``."""
    if name not in STUDIES:
        print(f"study {name} is not shown in docs/results.md (shown: {', '.join(STUDIES)})", file=sys.stderr)
        return False
    figures = docs / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    for old in figures.glob(f"{name}_*.png"):
        old.unlink()
    for png in sorted(out.rglob("*.png")):  # the report's own figures, beside it or in a subfolder
        shutil.copyfile(png, figures / study_figure_name(name, png.name))
    _copy_json(out / "summary.json", docs / "data" / f"{name}.json")
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("run", help="take OUT/summary.json of the main job, then rewrite the documents")
    p.add_argument("--out", default="results", type=Path, help="the run's output folder (default results)")
    p.add_argument("--force", action="store_true", help="take it even for a quick or partial run")
    p.add_argument("--docs", default=DOCS, type=Path, help=argparse.SUPPRESS)
    p = sub.add_parser("bench", help="take the benchmark's JSON, then rewrite the documents")
    p.add_argument("--json", default=Path("results/bench.json"), type=Path, help="default results/bench.json")
    p.add_argument("--docs", default=DOCS, type=Path, help=argparse.SUPPRESS)
    p = sub.add_parser("study", help="take a study's summary.json, then rewrite the documents")
    p.add_argument("name", help=f"the study ({', '.join(STUDIES)})")
    p.add_argument("--out", type=Path, default=None, help="the study's output folder (default results/studies/NAME)")
    p.add_argument("--docs", default=DOCS, type=Path, help=argparse.SUPPRESS)
    p = sub.add_parser("all", help="rewrite the documents from docs/data alone")
    p.add_argument("--docs", default=DOCS, type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.what == "run":
        taken = take_run(args.out, args.docs, args.force)
    elif args.what == "bench":
        taken = take_bench(args.json, args.docs)
    elif args.what == "study":
        taken = take_study(args.name, args.out or Path("results/studies") / args.name, args.docs)
    else:
        taken = True
    if not taken:
        return 1 if args.what == "study" else 0
    for path in write_documents(args.docs):
        print(f"rewrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
