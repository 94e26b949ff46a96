"""Assess a record (:func:`assess`) and apply the result (:func:`apply_quality`): mask, repair inputs, report."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import xarray as xr

from bayes_mr.data.derive import savgol_attrs, smooth_velocity
from bayes_mr.data.schema import DEVICE, FORCED, STRUCTURE
from bayes_mr.data.quality.config import QualityConfig
from bayes_mr.data.quality.consistency import consistent, repair_pair
from bayes_mr.data.quality.detectors import dilate, end_events, flats, jumps, rails, runs, spikes, velocity_range
from bayes_mr.data.quality.report import FAULT_KINDS, Fault, QualityReport, Repair

#: Channels that drive a simulation (repaired across their own faults).
INPUTS: dict[str, tuple[str, ...]] = {
    STRUCTURE: ("ground_acceleration",),
    DEVICE: ("displacement", "velocity"),
    FORCED: ("applied_force",),
}


#: Channels that carry the damper force, with their sign relative to it.
POLARITY = {"force": 1.0, "acceleration": -1.0}


def _velocity_of(ds: xr.Dataset) -> np.ndarray | None:
    """Piston / storey velocity for the graze test: measured, else derived from displacement."""
    if "velocity" in ds:
        return ds["velocity"].values.astype(float)
    if "displacement" in ds:
        x = ds["displacement"].values.astype(float)
        if np.isfinite(x).all() and x.size > 8:
            return smooth_velocity(x, float(ds.attrs.get("dt", 1.0)))
    return None


def default_channels(ds: xr.Dataset) -> tuple[str, ...]:
    """Channels assessed by default: data channels except voltage and package-derived ones."""
    return tuple(
        name
        for name, da in ds.data_vars.items()
        if name not in ("valid", "voltage") and da.dims == ("time",) and "derived" not in da.attrs
    )


def assess(ds: xr.Dataset, config: QualityConfig = QualityConfig()) -> tuple[np.ndarray, QualityReport]:  # noqa: B008 — frozen
    """Detect faults in a record.

    Parameters
    ----------
    ds : xarray.Dataset
        Record in the package schema.
    config : QualityConfig
        Thresholds.

    Returns
    -------
    valid : ndarray of bool, shape (n,)
        False where a fault (or its dilation) was found. Samples already
        invalid in ``ds`` are not included (see :func:`apply_quality`).
    report : QualityReport
        What was found, where, and why (``repaired`` is empty here).
    """
    cfg = config
    n = ds.sizes["time"]
    chans = cfg.channels if cfg.channels is not None else default_channels(ds)
    missing = [c for c in chans if c not in ds]
    if missing:
        raise KeyError(f"assess: channels {missing} not in the record")
    found: list[_Found] = []
    explained: dict[str, np.ndarray] = {}  # samples of a fault of that channel (no dilation)
    jumpy: dict[str, np.ndarray] = {}      # samples of a jump or out-of-range velocity
    series: dict[str, np.ndarray] = {}
    velocity = None
    for name in chans:
        x = ds[name].values.astype(float)
        bad = ~np.isfinite(x)
        if bad.any():
            found.append((name, "nonfinite", bad, np.nan, "NaN or inf value"))
            good = np.flatnonzero(~bad)
            x = np.interp(np.arange(n), good, x[good]) if good.size else np.zeros(n)
        jumpy[name] = np.zeros(n, bool)
        if np.ptp(x) == 0:  # a constant channel carries no information to judge
            explained[name] = bad.copy()
            continue
        series[name] = x
        polarity = POLARITY.get(name) if cfg.graze_exempt else None
        if polarity is not None and velocity is None:
            velocity = _velocity_of(ds)
        u = velocity if polarity is not None else None
        hits, explained[name], jumpy[name] = _channel_faults(name, x, bad.copy(), cfg, u, polarity)
        found.extend(hits)
    found = _drop_agreeing(found, jumpy, series, cfg, float(ds.attrs.get("dt", 1.0)))
    found.extend(_end_disturbance(series, explained, jumpy, cfg, n))
    invalid, faults = _masks(found, cfg, n)
    faults.sort(key=lambda f: (chans.index(f.channel), FAULT_KINDS.index(f.kind)))
    report = QualityReport(
        source=str(ds.attrs.get("source", "record")),
        n_samples=n,
        masked=int(invalid.sum()),
        faults=tuple(faults),
        channels=tuple(chans),
        config=cfg,
        dt=float(ds.attrs.get("dt", 1.0)),
    )
    return ~invalid, report


#: A detection: channel, fault kind, flagged samples, threshold, reason.
_Found = tuple[str, str, np.ndarray, float, str]


def _channel_faults(
    name: str, x: np.ndarray, skip: np.ndarray, cfg: QualityConfig, u: np.ndarray | None, polarity: float | None
) -> tuple[list[_Found], np.ndarray, np.ndarray]:
    """Rails, flat-lines, spikes, jumps and velocity range of one finite channel.

    ``skip`` (samples already explained, e.g. non-finite ones) is extended by
    every rail, flat-line and spike found: later detectors do not count them.
    Returns the detections, the explained samples and the jump / velocity-range samples.
    """
    found: list[_Found] = []
    jumpy = np.zeros(x.size, bool)
    if np.median(np.abs(np.diff(x, 2))) > 0 or not cfg.noise_guard:
        flag, thr, why = rails(x, cfg)
        if flag.any():
            found.append((name, "clipped", flag, thr, why))
            skip |= flag
        flag, thr, why = flats(x, cfg, skip)
        if flag.any():
            found.append((name, "flat", flag, thr, why))
            skip |= flag
    flag, thr, why = spikes(x, cfg, u, polarity or 1.0)
    flag &= ~skip
    if flag.any():
        found.append((name, "spike", flag, thr, why))
        skip |= flag
    flag, thr, why = jumps(x, cfg, skip, name in cfg.continuous)
    if flag.any():
        found.append((name, "jump", flag, thr, why))
        jumpy |= flag
    if name == "velocity":
        flag, thr, why = velocity_range(x, cfg)
        flag &= ~skip
        if flag.any():
            found.append((name, "velocity_range", flag, thr, why))
            jumpy |= flag
    return found, skip, jumpy


#: Detections that a displacement and a velocity agreeing with each other explain.
_MOTION_KINDS = ("jump", "velocity_range")


def _drop_agreeing(
    found: list[_Found], jumpy: dict[str, np.ndarray], series: dict[str, np.ndarray], cfg: QualityConfig, dt: float
) -> list[_Found]:
    """Without the jump / velocity-range samples on which a measured displacement and velocity agree.

    ``jumpy`` is updated in place (agreeing samples are no end-of-test events either).
    """
    if "displacement" not in series or "velocity" not in series:
        return found
    motion = [(i, f) for i, f in enumerate(found) if f[0] in ("displacement", "velocity") and f[1] in _MOTION_KINDS]
    if not motion:
        return found
    x = series["displacement"]
    flag = np.zeros(x.size, bool)
    for _, f in motion:
        flag |= f[2]
    lo, hi = np.quantile(x, [cfg.range_quantile, 1.0 - cfg.range_quantile])
    agree = consistent(flag, x, series["velocity"], dt, cfg.agree_c, cfg.spike_reach,
                       cfg.spike_floor * float(hi - lo))
    if not agree.any():
        return found
    out = []
    for i, f in enumerate(found):
        if any(i == j for j, _ in motion):
            f = (f[0], f[1], f[2] & ~agree, f[3], f[4])
            if not f[2].any():
                continue
        out.append(f)
    for name in ("displacement", "velocity"):
        jumpy[name] &= ~agree
    return out


def _end_disturbance(
    series: dict[str, np.ndarray],
    explained: dict[str, np.ndarray],
    jumpy: dict[str, np.ndarray],
    cfg: QualityConfig,
    n: int,
) -> list[_Found]:
    """End-of-test disturbance: a jump and its ringing in the final part → every triggering channel masked to the end."""
    start = n - max(int(round(cfg.end_fraction * n)), 2 * cfg.spike_reach)
    events = np.zeros(n, bool)
    triggers: dict[str, tuple[np.ndarray, float]] = {}
    for name, x in series.items():
        ok = ~(explained[name] | jumpy[name])  # the history is judged on clean samples
        # a position may end the test displaced (a frame that yielded): for it
        # only steps count, not values
        ev, thr = end_events(x, cfg, ok, use_values=name != "displacement")
        ev[start:] |= jumpy[name][start:]
        if ev.any():
            triggers[name] = (ev, thr)
            events |= ev
    if events.sum() < cfg.end_min_events:
        return []
    first = int(np.flatnonzero(events)[0])
    first = max(first - 1, 0)  # the step that leads into the first bad sample
    found: list[_Found] = []
    for name, (ev, thr) in triggers.items():
        flag = np.zeros(n, bool)
        flag[first:] = True
        why = (
            f"{int(ev.sum())} samples in the last {100 * cfg.end_fraction:g} % break the "
            f"record's history (|Δx| or |x − median| > {cfg.end_c:g} × its largest before, "
            "or a jump); masked from the first to the end"
        )
        found.append((name, "end_disturbance", flag, thr, why))
    return found


def _masks(found: list[_Found], cfg: QualityConfig, n: int) -> tuple[np.ndarray, list[Fault]]:
    """The union of the dilated detections (True = invalid) and one :class:`Fault` per detection."""
    invalid = np.zeros(n, bool)
    faults = []
    for name, kind, flag, thr, why in found:
        masked = dilate(flag, cfg.dilate)
        invalid |= masked
        faults.append(
            Fault(
                channel=name,
                kind=kind,
                detected=int(flag.sum()),
                count=int(masked.sum()),
                ranges=tuple(runs(masked)),
                threshold=float(thr),
                reason=why,
            )
        )
    return invalid, faults



def _repair_plan(ds: xr.Dataset, report: QualityReport) -> dict[str, np.ndarray]:
    """Input channel → samples to interpolate across (its own faults and the end disturbance)."""
    n = report.n_samples
    kind = ds.attrs.get("kind", DEVICE)
    plan: dict[str, np.ndarray] = {}
    end = np.zeros(n, bool)
    for f in report.faults:
        if f.kind == "end_disturbance":
            for a, b in f.ranges:
                end[a:b] = True
    for name in INPUTS[kind]:
        if name not in ds:
            continue
        m = end.copy()
        for f in report.faults:
            if f.channel == name:
                for a, b in f.ranges:
                    m[a:b] = True
        if m.any():
            plan[name] = m
    return plan


def apply_quality(ds: xr.Dataset, config: QualityConfig = QualityConfig()) -> xr.Dataset:  # noqa: B008 — frozen
    """Assess a record and return a copy with the mask, the report and repaired inputs.

    Sets ``valid`` (the existing mask AND the new one), attributes ``masked``
    (total invalid samples) and ``quality`` (JSON of :meth:`QualityReport.to_dict`),
    and — if ``config.repair`` — replaces input samples inside their own masked
    runs (ground acceleration in structure tests; displacement and a measured
    velocity in device tests; all inputs over an end disturbance) by linear
    interpolation between the nearest valid samples, holding the last valid
    value past the end. A velocity the package derived is re-derived from the
    repaired displacement (window chosen again for the repaired record).

    Parameters
    ----------
    ds : xarray.Dataset
    config : QualityConfig

    Returns
    -------
    xarray.Dataset
    """
    valid_new, report = assess(ds, config)
    out = ds.copy(deep=True)
    n = report.n_samples
    repairs = _repair_inputs(out, ds, report) if config.repair else []
    report = replace(report, repaired=tuple(repairs))
    old = out["valid"].values.astype(bool) if "valid" in out else np.ones(n, bool)
    valid = old & valid_new
    attrs = dict(out["valid"].attrs) if "valid" in out else {}
    out["valid"] = ("time", valid, attrs)
    out.attrs["masked"] = int((~valid).sum())
    out.attrs["quality"] = json.dumps(report.to_dict())
    return out


def _repair_inputs(out: xr.Dataset, ds: xr.Dataset, report: QualityReport) -> list[Repair]:
    """Interpolate ``out``'s input channels across their masked runs (in place); re-derive a derived velocity."""
    n = report.n_samples
    plan = _repair_plan(ds, report)
    repairs = _repair_motion(out, ds, plan, float(report.dt))
    for name, m in plan.items():
        good = ~m & np.isfinite(out[name].values)
        if not good.any():
            continue
        idx = np.arange(n)
        y = out[name].values.astype(float).copy()
        y[m] = np.interp(idx[m], idx[good], y[good])
        out[name] = ("time", y, dict(ds[name].attrs))
        repairs.append(Repair(channel=name, count=int(m.sum()), ranges=tuple(runs(m))))
    vel = out.get("velocity")
    rederive = any(r.channel == "displacement" for r in repairs)
    if vel is not None and vel.attrs.get("derived") == "savgol" and rederive:
        # re-derive, window included: the faults had widened the apparent bandwidth
        v, info = smooth_velocity(out["displacement"].values, float(out.attrs["dt"]), return_info=True)
        attrs = dict(vel.attrs)
        attrs.update(savgol_attrs(info))
        out["velocity"] = ("time", v, attrs)
    return repairs


#: How :func:`repair_pair` repairs a measured displacement and velocity.
_PAIR_METHOD = (
    "kept consistent with the other motion channel: displacement from the velocity's integral "
    "(closure spread over the run), velocity bridged so that it integrates to the displacement's change; "
    "both faulty: "
    "straight-line displacement and its slope (at rest where held)"
)


def _repair_motion(out: xr.Dataset, ds: xr.Dataset, plan: dict[str, np.ndarray], dt: float) -> list[Repair]:
    """Repair a measured displacement and velocity together (in place; their runs leave ``plan``).

    Bridging one of them alone by a straight line would make the simulator's
    two inputs disagree (a piston that moves with zero velocity); each is
    repaired from the other where the other is good (:func:`repair_pair`).
    """
    if ds.attrs.get("kind", DEVICE) != DEVICE or not {"displacement", "velocity"} & set(plan):
        return []
    if "displacement" not in ds or "velocity" not in ds or ds["velocity"].attrs.get("derived"):
        return []  # a derived velocity is re-derived from the repaired displacement instead
    n = ds.sizes["time"]
    bad_x = plan.get("displacement", np.zeros(n, bool))
    bad_v = plan.get("velocity", np.zeros(n, bool))
    if bad_x.all() or bad_v.all():
        return []
    plan.pop("displacement", None)
    plan.pop("velocity", None)
    x, v = repair_pair(ds["displacement"].values, ds["velocity"].values, bad_x, bad_v, dt)
    repairs = []
    for name, y, m in (("displacement", x, bad_x), ("velocity", v, bad_v)):
        if m.any():
            out[name] = ("time", y, dict(ds[name].attrs))
            repairs.append(Repair(channel=name, count=int(m.sum()), ranges=tuple(runs(m)), method=_PAIR_METHOD))
    return repairs


def report_of(ds: xr.Dataset) -> dict | None:
    """The quality report stored in a record's ``quality`` attribute (a dict), or None."""
    text = ds.attrs.get("quality")
    return json.loads(text) if text else None
