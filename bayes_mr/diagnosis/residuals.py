"""Residual analysis: where a model's simulation departs from the record.

Everything here is a plain function of arrays — the record's measured channels,
a model's simulated ones and the quality mask — so the same views serve the
baseline ("before") and the extended model ("after"):

* :func:`envelope` — the displacement-amplitude envelope (peak-following,
  decaying), the variable ``small_amplitude_regime`` switches on;
* :func:`binned` — residual mean ± SD in quantile bins of an explanatory
  variable (time, displacement, velocity, envelope, voltage) and the
  correlation ratio η² = Var(bin means) / Var(residual), the share of the
  residual variance that variable explains;
* :func:`autocorrelation`, :func:`ljung_box`, :func:`integrated_time` —
  whiteness of a residual; the integrated autocorrelation time τ is the
  variance-inflation factor of a mean of the residuals (1 for white noise);
* :func:`lag_of` — the lag [samples] at which a measured channel best matches
  its simulation (a ``sensor_delay`` signature), and :func:`crosscorrelation`
  of two series over ± lags.
* :func:`residual_views` assembles these for one prediction of one record.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import xarray as xr
from scipy import stats

from bayes_mr.numerics.stats import autocorrelation, integrated_time

#: Quantile bins of the binned views.
N_BINS = 24
#: Lags of the autocorrelation and cross-correlation views [samples].
MAX_LAG = 200
#: Lags of the Ljung–Box statistic.
LB_LAGS = 20


def envelope(x: np.ndarray, dt: float, t_env: float = 1.0) -> np.ndarray:
    """Peak-following amplitude envelope of ``x``, shape (n,).

    e_k = max(|x_k|, e_{k−1} · exp(−dt / t_env)), the discrete form of the
    envelope state of ``small_amplitude_regime`` (same decay time). Written as
    a running maximum in log space, so it is vectorised and cannot overflow.

    Parameters
    ----------
    x : array, shape (n,)
        Displacement [m].
    dt : float
        Sample interval [s].
    t_env : float
        Decay time [s].
    """
    a = np.abs(np.asarray(x, float))
    k = np.arange(a.size) * (dt / t_env)
    with np.errstate(divide="ignore"):
        log_a = np.log(a)
    return np.exp(np.maximum.accumulate(log_a + k) - k)


@dataclass(frozen=True)
class Binned:
    """Residual statistics in quantile bins of one variable.

    Attributes
    ----------
    center, mean, sd : ndarray, shape (b,)
        Bin median of the variable, residual mean and SD in the bin.
    eta2 : float
        Correlation ratio: share of the residual variance explained by the
        bin means (0 = the residual does not depend on the variable).
    """

    center: np.ndarray
    mean: np.ndarray
    sd: np.ndarray
    eta2: float


def binned(x: np.ndarray, r: np.ndarray, nbins: int = N_BINS) -> Binned:
    """Residual ``r`` against variable ``x`` in ``nbins`` quantile bins (both shape (n,))."""
    x = np.asarray(x, float)
    r = np.asarray(r, float)
    edges = np.unique(np.quantile(x, np.linspace(0, 1, nbins + 1)))
    if edges.size < 2:  # a constant variable explains nothing
        return Binned(np.array([x.mean()]), np.array([r.mean()]), np.array([r.std()]), 0.0)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    count = np.bincount(idx, minlength=edges.size - 1)
    s1 = np.bincount(idx, r, minlength=edges.size - 1)
    s2 = np.bincount(idx, r * r, minlength=edges.size - 1)
    keep = count > 3
    mean = s1[keep] / count[keep]
    sd = np.sqrt(np.maximum(s2[keep] / count[keep] - mean**2, 0.0))
    centers = np.array([np.median(x[idx == b]) for b in np.flatnonzero(keep)])
    var = r.var()
    between = np.sum(count[keep] * (mean - r.mean()) ** 2) / r.size
    return Binned(centers, mean, sd, float(between / var) if var > 0 else 0.0)


def ljung_box(r: np.ndarray, lags: int = LB_LAGS) -> tuple[float, float]:
    """Ljung–Box statistic Q = n(n+2) Σ_{k=1..h} ρ_k²/(n−k) and its χ²_h p-value.

    A small p-value says the residual is not white: the model leaves structure
    in time (or the input noise drives a response the output-error model does
    not follow).
    """
    n = np.asarray(r).size
    rho = autocorrelation(r, lags)[1:]
    k = np.arange(1, rho.size + 1)
    q = float(n * (n + 2) * np.sum(rho**2 / (n - k)))
    return q, float(stats.chi2.sf(q, rho.size))


def crosscorrelation(a: np.ndarray, b: np.ndarray, max_lag: int = MAX_LAG) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation c(ℓ) = corr(a_t, b_{t−ℓ}) for ℓ = −max_lag..max_lag.

    A peak at ℓ > 0 says ``a`` lags ``b`` by ℓ samples.

    Returns
    -------
    lags : ndarray of int, shape (2·max_lag + 1,)
    c : ndarray, shape (2·max_lag + 1,)
    """
    a = np.asarray(a, float) - np.mean(a)
    b = np.asarray(b, float) - np.mean(b)
    n = a.size
    max_lag = min(max_lag, n - 1)
    m = 2 * n
    cc = np.fft.irfft(np.fft.rfft(a, m) * np.conj(np.fft.rfft(b, m)), m)
    lags = np.arange(-max_lag, max_lag + 1)
    c = cc[lags % m]
    norm = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return lags, (c / norm if norm > 0 else np.zeros_like(c))


def lag_of(measured: np.ndarray, simulated: np.ndarray, max_lag: int = MAX_LAG) -> float:
    """Lag [samples, fractional] by which ``measured`` trails ``simulated``.

    Peak of their cross-correlation, refined by a parabola through the three
    samples around it. About 0 when the model's timing is right; a delayed
    sensor shows as its delay.
    """
    lags, c = crosscorrelation(measured, simulated, max_lag)
    j = int(np.argmax(c))
    if 0 < j < c.size - 1:
        den = c[j - 1] - 2 * c[j] + c[j + 1]
        shift = 0.5 * (c[j - 1] - c[j + 1]) / den if den < 0 else 0.0
        return float(lags[j] + shift)
    return float(lags[j])


@dataclass
class ChannelViews:
    """Residual views of one measured channel.

    Attributes
    ----------
    channel : str
    residual : ndarray, shape (n,)
        Measured − simulated [channel units]; 0 at masked samples.
    sigma : float
        RMS of the residual over valid samples.
    bins : dict of str → Binned
        Standardised residual against each explanatory variable.
    acf : ndarray
        Autocorrelation of the residual, lags 0..MAX_LAG.
    ljung_box_q, ljung_box_p : float
    tau : float
        Integrated autocorrelation time [samples].
    lag_samples : float
        Lag of the measured channel behind its simulation (:func:`lag_of`).
    """

    channel: str
    residual: np.ndarray
    sigma: float
    bins: dict[str, Binned]
    acf: np.ndarray
    ljung_box_q: float
    ljung_box_p: float
    tau: float
    lag_samples: float

    def summary(self) -> dict:
        """JSON-ready numbers (η² per variable, whiteness, lag)."""
        return {
            "rms": self.sigma,
            "eta2": {k: round(b.eta2, 6) for k, b in self.bins.items()},
            "ljung_box_q": self.ljung_box_q,
            "ljung_box_p": self.ljung_box_p,
            "tau_samples": self.tau,
            "lag_samples": self.lag_samples,
        }


@dataclass
class Views:
    """Residual views of every measured channel of one prediction.

    Attributes
    ----------
    channels : dict of str → ChannelViews
    variables : dict of str → ndarray
        Explanatory variables (valid samples only), shape (n_valid,).
    cross : dict of str → (lags, measured, simulated)
        Cross-correlations of pairs of measured channels, measured and simulated.
    input_cross : dict of str → (lags, c)
        Cross-correlation of each residual with the driving input.
    """

    channels: dict[str, ChannelViews]
    variables: dict[str, np.ndarray]
    cross: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)
    input_cross: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def summary(self) -> dict:
        return {c: v.summary() for c, v in self.channels.items()}


def explanatory_variables(record: xr.Dataset) -> dict[str, np.ndarray]:
    """Variables the residuals are viewed against, full length (n,).

    time [s], displacement [m], velocity [m/s] (device: the record's;
    structure: smoothed derivative of the measured displacement), amplitude
    envelope [m], and voltage [V] when the record's voltage varies.
    """
    from bayes_mr.data.derive import smooth_velocity

    dt = float(record.attrs["dt"])
    x = record["displacement"].values
    if record.attrs["kind"] == "device" and "velocity" in record:
        v = record["velocity"].values
    else:
        v = smooth_velocity(x, dt)
    out = {"time": record["time"].values, "displacement": x, "velocity": v, "envelope": envelope(x, dt)}
    if varying_voltage(record):
        out["voltage"] = record["voltage"].values
    return out


def varying_voltage(record: xr.Dataset) -> bool:
    """True when the record has a voltage channel that changes (more than 1 mV SD)."""
    return "voltage" in record and float(np.std(record["voltage"].values)) > 1e-3


def measured_channels(record: xr.Dataset) -> tuple[str, ...]:
    """Channels with a measurement to compare: the likelihood's outputs, plus a
    structure test's damper force when recorded."""
    from bayes_mr.data.schema import outputs_of

    out = list(outputs_of(record))
    if record.attrs["kind"] == "structure" and "force" in record:
        out.append("force")
    return tuple(out)


def residual_views(record: xr.Dataset, predicted: dict[str, np.ndarray]) -> Views:
    """Residual views of ``predicted`` (channel → simulated series (n,)) against ``record``.

    Only valid samples enter the statistics; time-ordered statistics (ACF,
    cross-correlation) use the residual with masked samples set to 0.
    """
    valid = record["valid"].values.astype(bool) if "valid" in record else np.ones(record.sizes["time"], bool)
    variables = explanatory_variables(record)
    kept = {k: v[valid] for k, v in variables.items()}
    channels = {}
    for c in measured_channels(record):
        if c not in predicted:
            continue
        y = record[c].values
        yhat = np.asarray(predicted[c], float)
        r = np.where(valid, y - yhat, 0.0)
        rv = r[valid]
        sd = float(np.sqrt(np.mean(rv**2)))
        z = rv / sd if sd > 0 else rv
        q, p = ljung_box(r)
        channels[c] = ChannelViews(
            channel=c, residual=r, sigma=sd,
            bins={k: binned(v, z) for k, v in kept.items()},
            acf=autocorrelation(r, MAX_LAG), ljung_box_q=q, ljung_box_p=p, tau=integrated_time(r),
            lag_samples=lag_of(np.where(valid, y, 0.0), np.where(valid, yhat, 0.0)),
        )
    views = Views(channels, kept)
    names = [c for c in measured_channels(record) if c in predicted]
    drive = "ground_acceleration" if record.attrs["kind"] == "structure" else "velocity"
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    if record.attrs["kind"] == "device":
        pairs = [("force", "displacement"), ("force", "velocity")]
    for a, b in pairs:
        ma = np.where(valid, record[a].values, 0.0)
        mb = np.where(valid, record[b].values if b in record else variables[b], 0.0)
        sa = np.where(valid, predicted[a], 0.0)
        sb = np.where(valid, predicted[b] if b in predicted else mb, 0.0)
        lags, cm = crosscorrelation(ma, mb)
        _, cs = crosscorrelation(sa, sb)
        views.cross[f"{a}~{b}"] = (lags, cm, cs)
    u = record[drive].values if drive in record else variables["velocity"]
    for c, cv in channels.items():
        views.input_cross[c] = crosscorrelation(cv.residual, np.where(valid, u, 0.0))
    return views
