"""diagnosis.extend: effects added on part A only, the gain measured on part B."""

import pytest

from bayes_mr.diagnosis.extend import extend
from bayes_mr.models import get_model
from bayes_mr.signals import make_signal
from bayes_mr.simulation.simulate import synthesize


def hidden_record(m_e: float | None, seed: int = 4):
    """A dahl damper driven by band-limited white noise (10 mm, 10 Hz; 1 % noise), inertia m_e hidden."""
    model = get_model("dahl+inertia" if m_e else "dahl")
    sig = make_signal("blwn", duration=4.0, fs=500.0, amplitude=10e-3, fmax=10.0, seed=seed)
    theta = model.theta("device", {"m_e": m_e} if m_e else {})
    return synthesize(model, theta, sig.time, sig.as_input("device"), noise=0.01, seed=seed + 77, source="extend")


def _parts(rec, share=0.6):
    cut = int(share * rec.sizes["time"])
    b = rec.isel(time=slice(cut, None))
    return rec.isel(time=slice(0, cut)), b.assign_coords(time=b["time"].values - float(b["time"].values[0]))


@pytest.mark.parametrize("hidden,rank", [(None, True), (3.0, True), (3.0, False)])
def test_extend_adds_the_hidden_physics_and_only_it(hidden, rank):
    """A dahl damper with hidden inertia (3 kg): inertia is added on A and lowers the error on B;
    the clean record gets nothing added. The base starts from the true dahl parameters."""
    rec = hidden_record(hidden)
    a, b = _parts(rec)
    theta = dict(zip(get_model("dahl").param_names("device"), get_model("dahl").theta("device")))
    out = extend(a, b, ("dahl", theta), candidates=("inertia", "shear_thinning", "force_offset"), rank=rank)
    if hidden:
        assert out["added"][0] == "inertia"
        assert out["extended"]["force_nrmse_b"] < 0.5 * out["base"]["force_nrmse_b"]
        assert out["extended"]["params"]["m_e"] == pytest.approx(3.0, rel=0.1)
    else:
        assert out["added"] == []
        assert out["extended"]["model"] == "dahl"
    assert out["unexplained_ratio_b"] is not None
