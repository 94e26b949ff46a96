"""The emcee posterior, in the stages of the algorithm (:mod:`.sampler` describes how they fit together).

* :mod:`.sampler` — :func:`~.sampler.sample` (start, adapt, chain, stop) and :func:`~.sampler.fit_mcmc`;
* :mod:`.settings` — :class:`~.settings.MCMCSettings`;
* :mod:`.start` — seeds and the initial walkers, :func:`~.start.start_from_lsq`;
* :mod:`.adapt` — the pilot and the adaptation rounds that fit the independence proposal;
* :mod:`.moves`, :mod:`.proposal` — how the walkers move, and the proposal fitted to them;
* :mod:`.chain` — running the chain with its HDF5 checkpoint, and :class:`~.chain.MCMCResult`;
* :mod:`.convergence` — burn-in, autocorrelation times, R-hat and the stopping rule;
* :mod:`.geometry` — what made a posterior slow to sample;
* :mod:`.budget` — whether a run fits its work budget, counted in log-density evaluations.
"""

from bayes_mr.inference.mcmc.chain import MCMCResult
from bayes_mr.inference.mcmc.sampler import fit_mcmc, sample
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.start import start_from_lsq

__all__ = ["MCMCResult", "MCMCSettings", "fit_mcmc", "sample", "start_from_lsq"]
