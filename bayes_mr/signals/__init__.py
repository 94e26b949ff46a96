"""Prescribed base (shake-table) or piston motions: the thesis's input signals.

Every signal of thesis Table 5.1 (the experiment) and signals I and II of the
numerical study (§3.8.1) as a :class:`Signal`: time plus displacement,
velocity and acceleration that are *consistent* — each is the derivative of the
one before, exactly, not by finite differences of noisy data:

* sweeps and the step ramp are analytic: velocity and acceleration are the
  closed-form derivatives of the displacement;
* BLWN is a trigonometric polynomial (filtered in the frequency domain) times
  a smooth taper: derivatives are its exact spectral derivatives by the
  product rule;
* earthquakes are acceleration records: velocity and displacement are their
  exact integrals from rest under the package's sampling convention (input
  linear between samples, ``docs/CONTRACT.md`` "Data"), after a documented baseline correction.

A structure test is driven by ``acceleration`` (the ground acceleration
ẍ_g), a device test by ``displacement`` (and ``velocity``); see
:meth:`Signal.as_input`.

Modules
-------
* :mod:`~bayes_mr.signals.signal` — the :class:`Signal` container and exact
  integration of a sampled acceleration;
* :mod:`~bayes_mr.signals.thesis` — the analytic signals (sweeps, step, BLWN)
  and how Table 5.1 is read where it is ambiguous;
* :mod:`~bayes_mr.signals.earthquake` — earthquake ground motions, resampled
  and baseline corrected;
* :mod:`~bayes_mr.signals.catalog` — the signals by name, their thesis
  defaults, :func:`make_signal` and the numerical-study presets.

``duration`` is always the length of the returned record: it holds
``round(duration · fs)`` samples at ``t_k = k / fs``, spanning [0, duration).
Units: SI throughout (``amplitude`` in metres, frequencies in Hz).
"""

from bayes_mr.signals.catalog import THESIS_FS, make_signal, signal_names, thesis_signal
from bayes_mr.signals.earthquake import BASELINES
from bayes_mr.signals.signal import Signal, integrate_acceleration

__all__ = [
    "BASELINES", "THESIS_FS", "Signal", "integrate_acceleration", "make_signal", "signal_names", "thesis_signal",
]
