"""Ensemble moves for emcee: the corrected DE snooker update and the names settings accept."""

from __future__ import annotations

import emcee
import numpy as np


class Snooker(emcee.moves.DESnookerMove):
    """DE snooker update (ter Braak & Vrugt 2008) with emcee 3.1.6's two errors fixed.

    emcee 3.1.6 projects on ``(s − z)/√|s − z|`` instead of the unit vector
    and uses ½(d − 1) in the Hastings factor; its chain is not stationary at
    the target (on a 4-d Gaussian it under-disperses, E[χ²] 15 MCSE low —
    ``tests/test_mcmc.py``). Fixed upstream after 3.1.6 (dfm/emcee#531);
    this is the corrected proposal, so the pinned emcee can stay.
    """

    def get_proposal(self, s, c, random):
        ns, ndim = s.shape
        q = np.empty_like(s)
        log_factor = np.empty(ns)
        for i in range(ns):
            w = np.array([c[j][random.randint(len(c[j]))] for j in range(3)])
            random.shuffle(w)
            z, z1, z2 = w
            delta = s[i] - z
            norm = np.linalg.norm(delta)
            u = delta / norm
            q[i] = s[i] + u * self.gammas * (np.dot(u, z1) - np.dot(u, z2))
            log_factor[i] = (ndim - 1.0) * (np.log(np.linalg.norm(q[i] - z)) - np.log(norm))
        return q, log_factor


#: Move names accepted in :attr:`MCMCSettings.moves`. ``emcee_snooker`` is emcee 3.1.6's biased
#: DESnookerMove, kept only so the test can show the bias.
MOVES = {
    "de": emcee.moves.DEMove,
    "snooker": Snooker,
    "stretch": emcee.moves.StretchMove,
    "emcee_snooker": emcee.moves.DESnookerMove,
}
