"""The emcee posterior: walkers started at the least-squares optimum, adapted moves, a chain run
until it has converged.

* :mod:`.sampler` — :func:`~.sampler.sample` and :func:`~.sampler.fit_mcmc`;
* :mod:`.settings` — :class:`~.settings.MCMCSettings`;
* :mod:`.walkers`, :mod:`.moves`, :mod:`.proposal` — where the walkers start and how they move;
* :mod:`.convergence` — burn-in, autocorrelation times, R-hat and the stopping rule;
* :mod:`.chain`, :mod:`.checkpoint` — the result and its HDF5 checkpoint;
* :mod:`.geometry` — what made a posterior slow to sample;
* :mod:`.wall_time` — whether a run fits a wall-time budget.
"""

from bayes_mr.inference.mcmc.chain import MCMCResult
from bayes_mr.inference.mcmc.sampler import fit_mcmc, sample
from bayes_mr.inference.mcmc.settings import MCMCSettings

__all__ = ["MCMCResult", "MCMCSettings", "fit_mcmc", "sample"]
