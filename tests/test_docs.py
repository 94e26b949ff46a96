"""The documents: README.md is for users and runs; docs/results.md and docs/performance.md are generated from
the JSON committed under docs/data/ and show no number that is not in it."""

import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
FIXTURE_BENCH = Path(__file__).resolve().parent / "fixtures" / "bench.json"
sys.path.insert(0, str(ROOT / "scripts"))

import docs_sections  # noqa: E402
import update_readme  # noqa: E402

# --- what counts as a number --------------------------------------------------------------------------------------

#: A decimal or scientific literal standing alone: not part of a name (k1, x0, tf_z_az, bouc-wen, "3-44",
#: "1-4"), a minus sign counted with it.
NUMBER = re.compile(r"(?<![\w.\-+−])[-−]?\d+(?:\.\d+)?(?:e[-+]?\d+)?(?![\w\-])")
#: Text whose digits are not measurements: code spans (commands, file names), link and image targets, the
#: generated-file comment, and a reference's year (``Spencer et al. (1997)``, ``Noël & Schoukens 2016``).
NOT_NUMBERS = [re.compile(p) for p in (r"`[^`]*`", r"\]\([^)]*\)", r"<!--.*?-->",
                                       r"(?:et al\.|& [A-Z]\w+) \(?(?:19|20)\d\d\)?")]
#: Fixed phrases of the templates that hold a number which is a rule of the method, not a measurement:
#: the MCMC convergence rule the main job's headline states beside each verdict (``bayes_mr/run/headline.py``;
#: the rule's constants are ``MCMCSettings``' defaults).
RULES = ("(≥ 50 τ, R-hat < 1.01)", "(≥ 50 τ and R-hat < 1.01 asked)")


def numbers_in(markdown: str) -> list[str]:
    """The number literals of a generated document (see :data:`NUMBER`, :data:`NOT_NUMBERS`, :data:`RULES`)."""
    for phrase in RULES:
        markdown = markdown.replace(phrase, " ")
    for pattern in NOT_NUMBERS:
        markdown = pattern.sub(" ", markdown)
    return NUMBER.findall(markdown)


def json_values(data) -> set[float]:
    """Every number a JSON document holds: its numeric leaves, the numbers written inside its strings and keys
    (record names, a table's "2.5 %" column), and a chain's length in integrated times (n_steps / tau_max of
    one row, as the headline writes it)."""
    out: set[float] = set()

    def walk(x):
        if isinstance(x, bool) or x is None:
            return
        if isinstance(x, (int, float)):
            out.add(float(x))
        elif isinstance(x, str):
            out.update(float(t.replace("−", "-")) for t in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", x))
        elif isinstance(x, dict):
            for k, v in x.items():
                walk(k)
                walk(v)
            if isinstance(x.get("n_steps"), (int, float)) and isinstance(x.get("tau_max"), (int, float)) \
                    and x["tau_max"]:
                out.add(x["n_steps"] / x["tau_max"])
        elif isinstance(x, list):
            for v in x:
                walk(v)

    walk(data)
    return out


def _resolution(token: str) -> float:
    """Half a unit in the last digit the generator printed (its rounding)."""
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10.0 ** (int(exponent or 0) - decimals)


#: How the templates turn a JSON value into the printed one: as it is, as a percentage, seconds as minutes.
SCALES = (1.0, 100.0, 1 / 60)


def from_json(token: str, values: set[float]) -> bool:
    """True when ``token`` is some JSON value as the generator prints it (rounded to the token's last digit)."""
    t = float(token.replace("−", "-"))
    half = _resolution(token) * (1 + 1e-9) + 1e-12 * abs(t)
    return any(abs(s * v - t) <= half or abs(abs(s * v) - t) <= half for v in values for s in SCALES
               if math.isfinite(v))


def test_the_number_rules_read_numbers_as_meant():
    text = ("spencer (ln BF 1.31e+03 over bouc-wen, k = 0.129); part B 0.1767 → 0.1178, tf_z_az = -4.675e+05, "
            "eq. 3-44, Spencer et al. (1997), periods 1-4, `bayes-mr study coverage --out results/x2`, "
            "![f](figures/run_1.png), 21.6–24.6 s, ×17.4, 100 %, (≥ 50 τ, R-hat < 1.01).")
    assert numbers_in(text) == ["1.31e+03", "0.129", "0.1767", "0.1178", "-4.675e+05", "21.6", "24.6", "17.4", "100"]
    values = json_values({"bf": 1309.7, "k": 0.12914, "rows": [{"a": 0.17671}, {"b": 0.11781}], "tf_z_az": -467512.0,
                          "seg": [21.6, 24.6], "x": "ratio ×17.43", "share": 1.0})
    assert all(from_json(t, values) for t in numbers_in(text))
    assert not from_json("0.1768", values) and not from_json("1.32e+03", values)
    assert from_json("12.3", json_values({"wall_s": 738.0}))  # minutes


# --- docs/results.md and docs/performance.md -------------------------------------------------------------------

def test_the_committed_documents_are_what_the_generator_makes_of_docs_data():
    """Byte for byte: nothing in docs/results.md or docs/performance.md is edited by hand or stale."""
    for name, text in docs_sections.documents(DOCS).items():
        assert (DOCS / name).read_text() == text, f"docs/{name} is stale: python scripts/update_readme.py all"


def _data_values(data_dir: Path) -> set[float]:
    values: set[float] = set()
    for path in data_dir.glob("*.json"):
        values |= json_values(json.loads(path.read_text()))
    return values


def test_every_number_in_the_results_comes_from_docs_data():
    text = (DOCS / "results.md").read_text()
    values = _data_values(DOCS / "data")
    stray = [t for t in numbers_in(text) if not from_json(t, values)]
    assert not stray, f"numbers in docs/results.md that no JSON under docs/data holds: {stray}"


def test_every_figure_the_results_link_is_committed():
    for name in ("results.md", "performance.md"):
        for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", (DOCS / name).read_text()):
            assert (DOCS / link).is_file(), link


def test_every_committed_figure_is_linked():
    """docs/figures holds the figures of the runs docs/data holds, and no others."""
    linked = {Path(link).name for name in ("results.md", "performance.md")
              for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", (DOCS / name).read_text())}
    assert {p.name for p in (DOCS / "figures").glob("*.png")} <= linked


def test_the_performance_page_from_a_bench_json(tmp_path):
    """`update_readme.py bench` takes a benchmark's JSON (the fixture has run_bench's keys, --boucwen and
    --compare included) into data/bench.json and writes the page; every number on it is in that JSON."""
    docs = tmp_path / "docs"
    docs.mkdir()
    assert update_readme.main(["bench", "--json", str(FIXTURE_BENCH), "--docs", str(docs)]) == 0
    assert json.loads((docs / "data" / "bench.json").read_text()) == json.loads(FIXTURE_BENCH.read_text())
    page = (docs / "performance.md").read_text()
    assert page == docs_sections.documents(docs)["performance.md"]
    assert "| speedup (as used / like for like) | 402× / 299× |" in page and "Not measured yet" not in page
    values = json_values(json.loads(FIXTURE_BENCH.read_text()))
    stray = [t for t in numbers_in(page) if not from_json(t, values)]
    assert not stray, stray
    # without bench.json the page says how to make it, and holds no number
    (docs / "data" / "bench.json").unlink()
    assert numbers_in(docs_sections.documents(docs)["performance.md"]) == []


def test_the_bench_fixture_has_every_key_the_bench_writes():
    """The fixture follows run_bench (its keys as the benchmark's sources write them)."""
    source = "".join(p.read_text() for p in (ROOT / "bayes_mr" / "bench").glob("*.py"))
    written = set(re.findall(r'"((?:(?:ukf|filterpy|train|lsq|mcmc|diagnose|boucwen|compare|simulate|kernel|'
                             r'inlined|max_state|compile|spencer)_[a-z_0-9]+)|speedup|threads)":', source))
    keys = set(json.loads(FIXTURE_BENCH.read_text()))
    assert len(written) > 30 and written <= keys, written - keys


def test_a_run_is_taken_into_docs_data_and_a_quick_one_is_not(tmp_path):
    out, docs = tmp_path / "results", tmp_path / "docs"
    out.mkdir()
    docs.mkdir()
    (out / "force_part_b.png").write_bytes(b"png")
    summary = json.loads((DOCS / "data" / "run.json").read_text()) if (DOCS / "data" / "run.json").is_file() \
        else None
    if summary is None:
        pytest.skip("no docs/data/run.json committed yet")
    summary = {**summary, "figures": {"force_b": str(out / "force_part_b.png")}, "diagnose": {}}
    (out / "summary.json").write_text(json.dumps({**summary, "full_job": False}))
    assert update_readme.main(["run", "--out", str(out), "--docs", str(docs)]) == 0
    assert not (docs / "data" / "run.json").exists()
    (out / "summary.json").write_text(json.dumps(summary))
    assert update_readme.main(["run", "--out", str(out), "--docs", str(docs)]) == 0
    assert json.loads((docs / "data" / "run.json").read_text()) == summary
    assert (docs / "figures" / "run_force_part_b.png").read_bytes() == b"png"
    assert "![force_b](figures/run_force_part_b.png)" in (docs / "results.md").read_text()


def test_a_study_is_taken_into_docs_data(tmp_path):
    """`update_readme.py study NAME`: the study's summary.json → data/NAME.json, its figures → figures/NAME_*.png,
    the section rendered by the study's own markdown() with its headings one level down."""
    out, docs = tmp_path / "out", tmp_path / "docs"
    (out / "figures").mkdir(parents=True)
    (out / "figures" / "z_scores.png").write_bytes(b"png")
    summary = {"quick": True, "level": 0.9, "n_members": 6, "n_devices": 2, "wall_s": 90.0, "failed": [],
               "records": {"fs_hz": 250.0, "duration_s": 6.0, "noise_range": [0.01, 0.05], "per_form": 2},
               "coverage": [{"engine": "lsq", "residual": "iid", "inside": 29, "n": 30, "coverage": 0.9667}],
               "per_form": [{"engine": "lsq", "residual": "iid", "form": "dahl", "inside": 8, "n": 8,
                             "coverage": 1.0}],
               "device_coverage": [{"engine": "lsq", "residual": "iid", "inside": 7, "n": 8, "coverage": 0.875}]}
    (out / "summary.json").write_text(json.dumps(summary))
    assert update_readme.main(["study", "coverage", "--out", str(out), "--docs", str(docs)]) == 0
    text = (docs / "results.md").read_text()
    assert "`bayes-mr study coverage --quick`" in text and "quick variant" in text
    assert "### Every form" in text and "![z-scores](figures/coverage_z_scores.png)" in text
    assert (docs / "figures" / "coverage_z_scores.png").read_bytes() == b"png"
    assert json.loads((docs / "data" / "coverage.json").read_text()) == summary
    stray = [t for t in numbers_in(text) if not from_json(t, json_values(summary))]
    assert not stray, stray


# --- README.md ----------------------------------------------------------------------------------------------------

README = (ROOT / "README.md").read_text()


def test_the_readme_is_short_and_for_users():
    assert len(README.splitlines()) <= 200
    # the README carries no project history: tests/test_history.py checks it with the rest of the tree
    for doc in ("docs/results.md", "docs/performance.md", "docs/ARCHITECTURE.md", "docs/CONTRACT.md"):
        assert doc in README and (ROOT / doc).is_file()


def test_the_readme_example_uses_public_names_only():
    import bayes_mr

    block = re.search(r"```python\n(.*?)```", README, re.DOTALL).group(1)
    names = set(re.findall(r"\bbm\.(\w+)", block))
    assert names and names <= set(bayes_mr.__all__), names - set(bayes_mr.__all__)


def test_the_readme_example_runs(tmp_path):
    """The README's Python example, as a user pastes it, in a fresh process in an empty folder."""
    block = re.search(r"```python\n(.*?)```", README, re.DOTALL).group(1)
    (tmp_path / "example.py").write_text(block)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    assert list(tmp_path.iterdir()) == [tmp_path / "example.py"]  # it writes nothing


def test_the_makefile_regenerates_the_documents():
    make = (ROOT / "Makefile").read_text()
    assert "scripts/update_readme.py run --out results" in make
    assert "scripts/update_readme.py bench --json results/bench.json" in make


def test_the_generator_needs_no_results_folder(tmp_path):
    """`update_readme.py all` rewrites the documents from docs/data alone."""
    docs = tmp_path / "docs"
    shutil.copytree(DOCS / "data", docs / "data") if (DOCS / "data").is_dir() else (docs / "data").mkdir(parents=True)
    if (DOCS / "figures").is_dir():
        shutil.copytree(DOCS / "figures", docs / "figures")
    assert update_readme.main(["all", "--docs", str(docs)]) == 0
    for name in ("results.md", "performance.md"):
        assert (docs / name).read_text() == (DOCS / name).read_text()


def test_every_module_path_the_documents_name_exists():
    """A path like ``bayes_mr/models/kernel.py`` in the README or docs/ points at a file of the tree."""
    named = set()
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        named |= set(re.findall(r"\bbayes_mr/[\w/]+\.py\b", doc.read_text()))
    missing = sorted(p for p in named if not (ROOT / p).is_file())
    assert not missing, f"paths named in the documents that do not exist: {missing}"
