"""A named cause survives what cannot matter: the rounding of another CPU, the thread count, the seed of the
starts, the kernel tier.

Each case is diagnosed twice: as it is, and with the record's outputs moved by a relative 1e-12 (the size of
one machine's rounding against another's), the effects' starts drawn from another seed and, in the slow
tier, the inlined kernel instead of the generic one. The two diagnoses must name the same cause — or, when
the record cannot tell two effects apart, report the same ambiguous set.
"""

import numba
import numpy as np
import pytest

from bayes_mr.diagnosis.diagnose import Search, diagnose
from records import case_id, effect_case, simulated_record

#: Hidden-effect cases of tests/diagnosis/test_diagnose.py, and the small-amplitude regime that a base dahl
#: half absorbs (the case whose ranking once turned on each candidate's estimated design effect).
CASES = [
    ("structure", "force_offset", 0, 0),
    ("structure", "cubic_stiffness", 1, 1),
    ("device", "low_velocity_rolloff", 0, 1),
]
ABSORBED_REGIME = {"small_amplitude_regime": {"r_s": 0.3, "x_s": 3e-4}}


def _rounded(record, seed: int):
    """``record`` with every measured channel moved by a relative 1e-12 (another machine's rounding)."""
    rng = np.random.default_rng(seed)
    out = record.copy(deep=True)
    for name, var in out.data_vars.items():
        if var.dtype.kind == "f" and var.dims == ("time",):
            out[name].values = var.values * (1.0 + 1e-12 * rng.standard_normal(var.shape))
    return out


def _answer(out: dict) -> tuple:
    return (out["cause"], frozenset(out["ambiguous"]))


def _twice(record, search=None, *, other_tier: bool = False, monkeypatch=None) -> tuple[dict, dict]:
    """The diagnosis as it is, and perturbed (rounding, seed, one thread; with ``other_tier`` the inlined kernel)."""
    kwargs = {} if search is None else {"search": search}
    first = diagnose(record, "dahl", progress=False, seed=0, **kwargs).to_dict()
    threads = numba.get_num_threads()
    if other_tier:
        monkeypatch.setenv("BAYES_MR_KERNELS", "inlined")
    numba.set_num_threads(1)
    try:
        second = diagnose(_rounded(record, 5), "dahl", progress=False, seed=1, **kwargs).to_dict()
    finally:
        numba.set_num_threads(threads)
    return first, second


def test_the_absorbed_regime_is_named_under_perturbation():
    rec = simulated_record("structure", "dahl", ABSORBED_REGIME, seed=3, signal="amp")
    first, second = _twice(rec, Search(max_effects=1))
    assert first["cause"] == "small_amplitude_regime", first["causes"][:3]
    assert _answer(second) == _answer(first), (first["causes"][:3], second["causes"][:3])


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_the_cause_survives_rounding_seed_and_threads(case):
    first, second = _twice(effect_case(*case))
    assert first["cause"] == case[1]
    assert _answer(second) == _answer(first), (first["causes"][:3], second["causes"][:3])


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_the_cause_survives_the_other_kernel_tier(case, monkeypatch):
    first, second = _twice(effect_case(*case), other_tier=True, monkeypatch=monkeypatch)
    assert _answer(second) == _answer(first), (first["causes"][:3], second["causes"][:3])
