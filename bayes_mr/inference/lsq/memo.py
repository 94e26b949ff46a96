"""The last simulations of single parameter sets, and their sensitivities, kept for the next call at the same φ.

A trust-region refinement ends where the next step of a fit starts: the re-weighted refinement
(:func:`bayes_mr.diagnosis.fits.converge`), the noise estimate and the Laplace covariance each ask again for
the simulation and the Jacobian the last accepted step had. On the bench's diagnose (``bayes-mr bench``) a
sixth of the sensitivity runs and a quarter of the simulations were such repeats. Simulations are
deterministic in (likelihood, φ, options), so the repeat is the same numbers: :func:`simulated` and
:func:`slopes` hand back the kept ones.

Bounded: at most :data:`MEMO_SIZE` entries and :data:`MEMO_BYTES` of arrays (the newest entry is always
kept), the least recently used dropped first; an entry holds its likelihood weakly and goes with it. Arrays
handed out are read-only, so no caller can change what the next one is given. Thread-safe (diagnose refits
candidates side by side); two threads asking for the same φ at once may both simulate it, which costs time,
not numbers.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from typing import Callable

import numpy as np

from bayes_mr.likelihood.output_error import OutputError

#: Most entries kept: a few per fit running side by side (a fit's next step asks for its last point, or for
#: the best of a few it refined).
MEMO_SIZE = 16
#: Most bytes of arrays kept (a 30 s, 1 kHz, three-channel record with 5 parameters: ~4.3 MB an entry).
MEMO_BYTES = 256 * 2**20

_entries: OrderedDict = OrderedDict()
_lock = threading.Lock()


def _key(lik: OutputError, phi: np.ndarray, options: dict) -> tuple:
    return id(lik), np.asarray(phi, float).tobytes(), tuple(sorted(options.items()))


def _get(lik: OutputError, key: tuple) -> dict | None:
    with _lock:
        entry = _entries.get(key)
        if entry is None or entry["lik"]() is not lik:  # an id reused by a new likelihood is not a hit
            return None
        _entries.move_to_end(key)
        return entry


def _keep(key: tuple, entry: dict) -> None:
    """Store ``entry`` (or count its new arrays) and drop the least recently used beyond the bounds."""
    entry["nbytes"] = sum(a.nbytes for a in (entry["yhat"], entry.get("dy")) if isinstance(a, np.ndarray))
    with _lock:
        for dead in [k for k, e in _entries.items() if e["lik"]() is None]:  # its likelihood is gone
            del _entries[dead]
        _entries[key] = entry
        _entries.move_to_end(key)
        while len(_entries) > 1 and (len(_entries) > MEMO_SIZE
                                     or sum(e["nbytes"] for e in _entries.values()) > MEMO_BYTES):
            _entries.popitem(last=False)


def _read_only(a):
    if isinstance(a, np.ndarray):
        a.flags.writeable = False
    return a


def simulated(lik: OutputError, phi: np.ndarray, **options):
    """``lik.predict(phi, **options)`` of one parameter set φ (p,): (ŷ (1, N, C), Simulation), kept.

    ŷ is read-only; the simulation object is shared with the next caller at the same φ (read it, do not
    change it).
    """
    key = _key(lik, phi, options)
    entry = _get(lik, key)
    if entry is None:
        yhat, sim = lik.predict(phi, **options)
        entry = {"lik": weakref.ref(lik), "yhat": _read_only(yhat), "sim": sim}
        _keep(key, entry)
    return entry["yhat"], entry["sim"]


def slopes(lik: OutputError, phi: np.ndarray, options: dict, compute: Callable[[], np.ndarray | None]):
    """∂ŷ/∂φ at φ as ``compute()`` gives it (an array, read-only once kept, or None for no slope), kept
    beside φ's simulation (:func:`simulated` with the same ``options``; computed and not kept if that is
    no longer held)."""
    key = _key(lik, phi, options)
    entry = _get(lik, key)
    if entry is None:
        return compute()
    if "dy" not in entry:
        entry["dy"] = _read_only(compute())
        _keep(key, entry)
    return entry["dy"]
