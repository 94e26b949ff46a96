"""The memo of single-φ simulations and sensitivities: the same numbers as without it, bounded, never shared."""

import numpy as np
import pytest

from bayes_mr.diagnosis.fits import converge
from bayes_mr.inference.lsq import memo
from bayes_mr.inference.lsq.least_squares import laplace
from bayes_mr.inference.lsq.refine import Residuals, refine
from bayes_mr.likelihood.output_error import OutputError
from records import structure_record


@pytest.fixture
def lik():
    rec, _ = structure_record("dahl+force_offset", {"f0": 2.0}, n=1500, seed=3)
    return OutputError("dahl+force_offset", rec)


def _counting(lik):
    calls = []
    predict = lik.predict

    def counted(phi, *args, **kw):
        calls.append(np.array(phi))
        return predict(phi, *args, **kw)

    lik.predict = counted
    return calls


def test_a_repeat_is_the_kept_simulation_read_only(lik):
    calls = _counting(lik)
    phi = 0.5 * (lik.phi_lo + lik.phi_hi)
    yhat, sim = memo.simulated(lik, phi)
    again, sim_again = memo.simulated(lik, phi.copy())
    assert len(calls) == 1 and again is yhat and sim_again is sim
    fresh, _ = OutputError.predict(lik, phi)
    np.testing.assert_array_equal(yhat, fresh)
    with pytest.raises(ValueError):
        yhat[0, 0, 0] = 1.0  # read-only: no caller can change what the next one is given
    memo.simulated(lik, phi, n_max=32)  # other options: another simulation
    other = phi.copy()
    other[0] += 1e-3
    memo.simulated(lik, other)
    assert len(calls) == 3


def test_another_likelihood_never_gets_the_kept_run(lik):
    phi = 0.5 * (lik.phi_lo + lik.phi_hi)
    memo.simulated(lik, phi)
    twin = OutputError("dahl+force_offset", structure_record("dahl+force_offset", {"f0": 2.0}, n=1500, seed=4)[0])
    calls = _counting(twin)
    memo.simulated(twin, phi)
    assert len(calls) == 1


def test_bounded_by_entries_and_bytes(lik, monkeypatch):
    phis = lik.phi_lo + np.linspace(0.2, 0.8, 6)[:, None] * (lik.phi_hi - lik.phi_lo)
    monkeypatch.setattr(memo, "MEMO_SIZE", 3)
    for phi in phis:
        memo.simulated(lik, phi)
    assert len(memo._entries) == 3
    monkeypatch.setattr(memo, "MEMO_BYTES", 1)  # below one entry: the newest is still kept
    memo.simulated(lik, phis[0])
    assert len(memo._entries) == 1
    calls = _counting(lik)
    memo.simulated(lik, phis[0])
    assert not calls


def _fit(lik):
    sd = np.full(len(lik.channels), 1.0)
    start = lik.phi_lo + 0.45 * (lik.phi_hi - lik.phi_lo)
    phi = refine(lik, start, sd, 200).x
    phi = converge(lik, phi, refined_at=sd)
    res = laplace(lik, phi, replicas=0)
    return phi, Residuals(lik, res.sigma).jacobian(phi), res


def test_a_fit_with_the_memo_is_the_fit_without_it(lik, monkeypatch):
    """Refinement, re-weighting and Laplace reuse the last step's run and slopes: bit for bit what recomputing
    them gives, with fewer sensitivity runs."""
    from bayes_mr.simulation import sensitivity

    runs = []
    real = sensitivity.output_sensitivities
    monkeypatch.setattr(sensitivity, "output_sensitivities", lambda *a, **k: runs.append(1) or real(*a, **k))
    phi, J, res = _fit(lik)
    with_memo = len(runs)
    runs.clear()
    monkeypatch.setattr(memo, "_get", lambda lik, key: None)
    phi0, J0, res0 = _fit(lik)
    np.testing.assert_array_equal(phi, phi0)
    np.testing.assert_array_equal(J, J0)
    np.testing.assert_array_equal(res.cov_phi, res0.cov_phi)
    assert res.log_evidence == res0.log_evidence
    assert with_memo < len(runs)


def test_an_entry_goes_with_its_likelihood(lik):
    import gc

    gone, _ = structure_record("dahl", {}, n=500, seed=5)
    gone = OutputError("dahl", gone)
    memo.simulated(gone, 0.5 * (gone.phi_lo + gone.phi_hi))
    del gone
    gc.collect()
    memo.simulated(lik, 0.5 * (lik.phi_lo + lik.phi_hi))
    assert all(e["lik"]() is not None for e in memo._entries.values())
