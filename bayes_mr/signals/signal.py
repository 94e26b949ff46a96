"""The :class:`Signal` container and the exact integration of a sampled acceleration."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class Signal:
    """A prescribed motion sampled uniformly from t = 0.

    Attributes
    ----------
    time : ndarray, shape (n,)
        Sample times [s], ``k / fs``.
    displacement : ndarray, shape (n,)
        Displacement [m].
    velocity : ndarray, shape (n,)
        Velocity [m/s], the derivative of ``displacement``.
    acceleration : ndarray, shape (n,)
        Acceleration [m/s²], the derivative of ``velocity``.
    name : str
        Generator name (see :func:`signal_names`).
    params : dict
        Every setting that produced the signal (JSON-serialisable), including
        defaults that were filled in and the seed of random signals.

    The arrays are read-only copies.
    """

    time: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    name: str
    params: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = None
        for attr in ("time", "displacement", "velocity", "acceleration"):
            arr = np.array(getattr(self, attr), dtype=float)  # copy: the caller keeps theirs
            if arr.ndim != 1:
                raise ValueError(f"Signal.{attr} must be 1-D, got shape {arr.shape}")
            if n is None:
                n = arr.size
            elif arr.size != n:
                raise ValueError(f"Signal.{attr} has {arr.size} samples, time has {n}")
            if not np.isfinite(arr).all():
                raise ValueError(f"Signal.{attr} has non-finite values")
            arr.flags.writeable = False
            object.__setattr__(self, attr, arr)
        if n < 2:
            raise ValueError("a Signal needs at least 2 samples")
        object.__setattr__(self, "params", dict(self.params))

    def __len__(self) -> int:
        return self.time.size

    @property
    def dt(self) -> float:
        """Sampling interval [s]."""
        return float((self.time[-1] - self.time[0]) / (self.time.size - 1))

    @property
    def fs(self) -> float:
        """Sampling rate [Hz]."""
        return 1.0 / self.dt

    def as_input(self, kind: str) -> dict[str, np.ndarray]:
        """The channels that drive a test of the given kind.

        Parameters
        ----------
        kind : {"structure", "device"}
            Structure test: the signal is the ground motion →
            ``{"ground_acceleration": acceleration}``. Device test: the signal
            is the piston motion → ``{"displacement": ..., "velocity": ...}``.

        Returns
        -------
        dict
            Channel name (package schema) → array, shape (n,).
        """
        if kind == "structure":
            return {"ground_acceleration": self.acceleration}
        if kind == "device":
            return {"displacement": self.displacement, "velocity": self.velocity}
        raise ValueError(f"kind must be 'structure' or 'device', got {kind!r}")


# --------------------------------------------------------------------------- #
# Kinematics helpers
# --------------------------------------------------------------------------- #
def integrate_acceleration(a: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and displacement from rest of an acceleration linear between samples.

    Exact for a piecewise-linear acceleration (the package's sampling
    convention): ``v_{k+1} = v_k + dt (a_k + a_{k+1})/2`` and
    ``x_{k+1} = x_k + dt v_k + dt² (2 a_k + a_{k+1})/6``.

    Parameters
    ----------
    a : array, shape (n,)
        Acceleration [m/s²].
    dt : float
        Sampling interval [s].

    Returns
    -------
    v : ndarray, shape (n,)
        Velocity [m/s], ``v[0] = 0``.
    x : ndarray, shape (n,)
        Displacement [m], ``x[0] = 0``.
    """
    a = np.asarray(a, dtype=float)
    v = np.concatenate(([0.0], np.cumsum(0.5 * dt * (a[:-1] + a[1:]))))
    dx = dt * v[:-1] + dt * dt * (2.0 * a[:-1] + a[1:]) / 6.0
    return v, np.concatenate(([0.0], np.cumsum(dx)))

