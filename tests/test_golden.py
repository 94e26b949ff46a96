"""Golden fits: the redesign (issue 12) must reproduce what the tree gave before it.

``tests/golden/fits.json`` was written by ``tests/golden/capture.py`` on the tree
before the estimator protocol and the one results builder. The same seed must
give the same parameters, evidence and scores for every estimator — bit for bit
where the arithmetic is unchanged, so the tolerance is round-off (1e-9 relative).
"""

import json
import math
import sys
from pathlib import Path

import pytest

GOLDEN = Path(__file__).parent / "golden"
sys.path.insert(0, str(GOLDEN))

from cases import CASES, fit_case  # noqa: E402

EXPECTED = json.loads((GOLDEN / "fits.json").read_text())


def assert_close(a, b, path=""):
    """Assert nested JSON values equal, floats to round-off (1e-9 relative)."""
    if isinstance(a, dict):
        assert set(a) == set(b), f"{path}: keys {sorted(a)} != {sorted(b)}"
        for k in a:
            assert_close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, float) and isinstance(b, (int, float)):
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12), f"{path}: {a!r} != {b!r}"
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


@pytest.mark.parametrize("name", sorted(CASES))
def test_golden_fit(name):
    assert_close(fit_case(name), EXPECTED[name], name)
