"""The filter's output map (models.kernel.forces) gives deriv's forces for every form, effect and kind."""

import numpy as np
import pytest

from bayes_mr.models import get_model, kernel
from bayes_mr.models.forms import FORMS

#: Effects that change the force (or the states it reads); each form is checked alone and under all of them
#: (less those a form models itself, like spencer's voltage dependence).
FORCE_EFFECTS = ("force_offset", "voltage_dependence", "stiffness_drift", "asymmetry", "small_amplitude_regime",
                 "low_velocity_rolloff", "cubic_stiffness", "stribeck_friction")
WITH_EFFECTS = ["+".join([f, *(e for e in FORCE_EFFECTS if e not in FORMS[f].built_in)]) for f in FORMS]


@pytest.mark.parametrize("kind", ["structure", "device", "forced"])
@pytest.mark.parametrize("name", [*FORMS, *WITH_EFFECTS])
def test_forces_are_the_forces_of_deriv(name, kind):
    model = get_model(name)
    lay, cst = model.layout(kind), model.constants(50.0)
    theta = model.theta(kind, {})
    rng = np.random.default_rng(7)
    ns = int(lay[kernel.L_NS])
    for _ in range(20):
        s = rng.uniform(-1.0, 1.0, ns) * np.where(np.arange(ns) < 2, 0.01, 0.9)
        a = np.array([rng.normal(), rng.normal() * 0.1, rng.uniform(0.0, 2.0)])
        t = rng.uniform(0.0, 10.0)
        want = kernel.deriv(lay, cst, theta, t, a, s, np.zeros(ns))
        got = kernel.forces(lay, cst, theta, t, a, s, np.zeros(ns))
        assert got == want  # the same arithmetic: bit for bit
