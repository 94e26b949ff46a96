"""Seeds and the HDF5 checkpoint of an emcee run (:func:`bayes_mr.inference.mcmc.sampler.sample`).

A run's ``seed`` → :class:`numpy.random.SeedSequence`; one child seeds the
:class:`numpy.random.Generator` that draws the initial walkers, the other the
MT19937 ``RandomState`` emcee uses for its moves. The checkpoint (emcee
``HDFBackend``) stores the chain and that random state after every step, and
the seed's entropy and the run's settings as attributes of its group, so a
resumed run is checked against the seed it continues.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import emcee
import numpy as np

from bayes_mr.numerics.synthetic_noise import as_seed_sequence


def run_seeds(seed) -> tuple[np.random.Generator, dict, str]:
    """The Generator of the initial walkers, emcee's RandomState state, and the seed's entropy.

    Parameters
    ----------
    seed : int or SeedSequence

    Returns
    -------
    init_rng : numpy.random.Generator
        Draws the initial walkers.
    move_state : dict
        State of the legacy ``RandomState`` emcee's moves draw from (we set
        its state, never the global one).
    entropy : str
        The seed's entropy, with the spawn key of a spawned child (a child
        shares its parent's entropy: the spawn key tells them apart).
    """
    seq = as_seed_sequence(seed)
    init_seq, move_seq = seq.spawn(2)
    rs = np.random.RandomState(np.random.MT19937(move_seq))
    entropy = str(seq.entropy) + ("/" + "-".join(map(str, seq.spawn_key)) if seq.spawn_key else "")
    return np.random.default_rng(init_seq), rs.get_state(), entropy


def seed_of(entropy: str) -> np.random.SeedSequence:
    """The SeedSequence a :func:`run_seeds` entropy string names (``"ENTROPY"`` or ``"ENTROPY/K1-K2…"``)."""
    ent, _, key = str(entropy).partition("/")
    return np.random.SeedSequence(int(ent), spawn_key=tuple(int(k) for k in key.split("-") if k))


def open_backend(settings, group: str, shape: tuple[int, int], entropy: str) -> tuple[object | None, bool]:
    """The run's HDF5 backend, and whether it resumes a stored chain.

    Parameters
    ----------
    settings : MCMCSettings
        Its ``backend`` (file, or None for memory only) and ``resume``.
    group : str
        HDF5 group of the chain inside the file.
    shape : (int, int)
        (walkers, dimension) of this run.
    entropy : str
        Seed entropy of this run (:func:`run_seeds`).

    Returns
    -------
    backend : emcee.backends.HDFBackend or None
    resuming : bool
        True when ``settings.resume`` and the group holds a chain; else the
        group is reset and stamped with the seed entropy and settings.

    Raises
    ------
    ValueError
        If the stored chain was made with another seed or another shape.
    """
    if settings.backend is None:
        return None, False
    backend = emcee.backends.HDFBackend(str(settings.backend), name=group)
    if settings.resume and backend.initialized and backend.iteration > 0:
        with backend.open() as f:
            stored = f[group].attrs.get("bayes_mr_seed_entropy")
        if stored is not None and str(stored) != entropy:
            raise ValueError(f"{settings.backend}[{group}]: checkpoint was made with seed entropy {stored}, "
                             f"not {entropy}; resume with the same seed or start afresh (resume=False)")
        if backend.shape != shape:
            raise ValueError(f"{settings.backend}[{group}]: checkpoint holds {backend.shape} (walkers, dim), "
                             f"this run needs {shape}")
        return backend, True
    Path(settings.backend).parent.mkdir(parents=True, exist_ok=True)
    backend.reset(*shape)
    with backend.open("a") as f:
        f[group].attrs["bayes_mr_seed_entropy"] = entropy
        f[group].attrs["bayes_mr_settings"] = json.dumps({**asdict(settings), "seed": entropy}, default=str)
    return backend, False
