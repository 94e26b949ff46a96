"""Simulation of any model under any input: the compiled forward model and what drives it.

* :mod:`.simulate` — :func:`~.simulate.simulate` (a model's outputs under a record's input, batched
  over parameter sets) and :func:`~.simulate.synthesize` (a noisy record from a model);
* :mod:`.inputs` — :class:`~.inputs.Inputs`, a test's input rows on a uniform grid;
* :mod:`.input_grid` — how the input is read between samples (linear or band-limited).
"""

from bayes_mr.simulation.inputs import Inputs
from bayes_mr.simulation.simulate import Simulation, simulate, synthesize

__all__ = ["Inputs", "Simulation", "simulate", "synthesize"]
