"""Numerical helpers with no domain in them: robust statistics and seeded random signals.

* :mod:`.stats` — robust SD, autocorrelation, integrated times, HAC bandwidth;
* :mod:`.synthetic_noise` — seeds and generators, band-limited white noise as the thesis adds it.
"""
