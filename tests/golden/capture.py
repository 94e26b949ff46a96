"""Capture the golden fits the estimators must reproduce (rerun only to change the reference on purpose).

``python tests/golden/capture.py`` writes ``tests/golden/fits.json``: for a small
structure test and a small device test, the summary of every estimator with a
fixed seed. ``tests/test_golden.py`` refits and compares.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))

from cases import CASES, fit_case  # noqa: E402


def main() -> None:
    out = {name: fit_case(name) for name in CASES}
    (HERE / "fits.json").write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
