"""Thresholds of the quality-control fault detectors (:class:`QualityConfig`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class QualityConfig:
    """Thresholds of the fault detectors; every one is relative to the record itself.

    Notation: x is a channel, Δx its sample-to-sample step, R = max x − min x,
    R_rob = q_{1−range_quantile}(x) − q_{range_quantile}(x) its robust range,
    q_p(·) the p-quantile over the record.

    Each threshold is documented where it is declared, below.

    Notes
    -----
    Calibration (no false alarm is the hard requirement). With these defaults
    nothing was masked in 816 clean simulated records — device tests
    (random, frequency sweep, amplitude sweep; 0.5–10 mm RMS; 10 N–10 kN;
    1024–4096 Hz; 5–50 Hz bandwidth) and structure tests (the same plus an
    earthquake-like record linearly resampled from 50 Hz) at 0, 0.1, 1 and 5 %
    noise, 6 seeds — nor in 360 records of the sharpest case (tanh force,
    fs ≈ 50 × bandwidth, 40 seeds), nor in the NEES record. The largest ratio
    of a detector's statistic to its threshold over those records was 0.72
    (spike; 0.85 in the sharpest case), 0.58 (jump), 0.40 (velocity range),
    0.76 (end of test); rail and flat-line statistics never approached theirs.
    Detection (tests): rails of 150–200 samples, spikes ≥ 2 SD on the real
    record and ≥ 1 SD on smooth channels, dropouts of ≥ 25 samples, and the
    jump-and-ring end disturbance are all masked; smaller spikes next to
    force flips are partly missed.

    The spike test assumes an oversampled record (fs ≳ 50 × its bandwidth, as
    lab records are: thesis 4096 Hz for ≤ 20 Hz, NEES 3 kHz for ≤ 50 Hz); a
    genuine excursion as short as ``spike_width`` samples is then impossible.
    """

    channels: tuple[str, ...] | None = None
    """Channels to assess. Default: every data channel except ``voltage``
    (a switched command is piecewise constant by design: repeated values and
    steps are its nature) and channels derived by the package
    (``attrs["derived"]``), which are re-derived from their repaired source."""

    clip_min_count: int = 3
    """Clipping (rail): the channel's extreme value (max or min, within
    ``clip_tol`` · R) must be hit at least this many times …"""

    clip_ratio: float = 3.0
    """… and at least ``clip_ratio`` × as often as the most repeated value
    within ``clip_zone`` · R of it …"""

    clip_tol: float = 1e-12
    """… (relative tolerance for "at the rail": float round-off only, a
    saturated converter repeats its value exactly) …"""

    clip_min_run: int = 2
    """… and the signal must sit on the rail for at least this many
    consecutive samples somewhere. A continuous signal hits its extreme
    once, a quantised one about as often as the values next to it, and
    the isolated sampled peaks of a noise-free constant-amplitude sine can
    coincide to 1e-10 R; a rail holds the signal while it is beyond it."""

    clip_zone: float = 0.1
    """Width of the zone next to the extreme (fraction of R) whose values set
    the natural repetition count."""

    approach_tol: float = 1e-6
    """Rail and flat-line tests: a run of equal values with a neighbour within
    ``approach_tol`` · R of it is a noise-free saturation (e.g. a simulated
    Dahl force reaching ±F_d in floating point), not a fault. Measured
    channels never qualify: their neighbours differ by noise or at least
    one converter step (≥ 1e-6 R up to 20 bits)."""

    flat_min_run: int = 5
    """Flat-line / dropout: a run of exactly repeated values (exact zeros or a
    held last value) of at least this many samples …"""

    flat_ratio: float = 3.0
    """… and at least ``flat_ratio`` × the ``flat_quantile`` quantile of the
    channel's run lengths (1 for noisy float data; larger for coarsely
    quantised channels, which repeat values naturally), not touching the
    first or last sample (a channel flat at the start or end of a test is
    at rest, not dropped out)."""

    flat_quantile: float = 0.999
    """Quantile of the run lengths that ``flat_ratio`` multiplies."""

    spike_width: int = 2
    """Longest excursion treated as a spike [samples]; the running median has
    ``2 * spike_width + 1`` samples."""

    spike_c: float = 10.0
    """Spike: |x − running median| > ``spike_c`` × σ_r, σ_r = 1.4826 · MAD over
    the record of the residual from the median of the ``2 * spike_width``
    neighbours (the sample itself left out, so that σ_r is not zero on
    monotone stretches) …"""

    spike_local_c: float = 4.0
    """… and > ``spike_local_c`` × the largest |Δx| within ``spike_reach``
    samples on either side, outside the spike itself. This keeps corners
    (velocity reversals, force flips) from being called spikes: at a corner
    of a continuous signal the residual is at most ``spike_width`` steps,
    and the neighbouring steps are as large. A spike next to a genuine
    sharp transition is found only if it dwarfs that transition's steps."""

    spike_reach: int = 6
    """Half-width of the neighbourhood of the local test [samples]."""

    spike_floor: float = 1e-3
    """The spike threshold is at least ``spike_floor`` · R_rob (σ_r of a
    noise-free channel is ~0; an excursion of 0.1 % of the range is no
    fault worth masking)."""

    graze_exempt: bool = True
    """Force and storey acceleration (−force/m): a short excursion where the
    velocity (measured, else derived from displacement) dips towards zero
    and comes back on the same side, in the direction a damper's force
    takes at reversed velocity and within R_rob, is the damper following
    a brief near-reversal, not a spike — a viscoplastic law such as
    F ∝ tanh(ẋ / 5 mm/s) does this within 1–3 samples at 2 kHz. Only
    such grazes of a moving piston are exempt, not every reversal and
    not a rig at rest."""

    continuous: tuple[str, ...] = ("displacement", "velocity")
    """Channels that cannot step physically (a piston or storey position, an
    imposed velocity): their jump test is relative to their own steps.
    Force and accelerations step legitimately — an MR damper's force flips
    by its whole range within a few samples at a velocity reversal, and a
    record may hold only a few reversals — so their jump test is relative
    to their range."""

    jump_quantile: float = 0.99
    """Jump in a continuous channel: |Δx| > ``jump_c`` × q_{jump_quantile}(|Δx|),
    far beyond the record's own large steps."""

    jump_c: float = 8.0
    """Multiple of the ``jump_quantile`` step that is a jump (continuous channels)."""

    jump_range: float = 1.5
    """Jump in another channel: |Δx| > ``jump_range`` × R_rob, a step larger
    than the channel's robust range, which no sample-to-sample change of a
    real signal can be. Steps into or out of an already detected spike,
    rail or flat-line are that fault, not a jump."""

    range_quantile: float = 0.005
    """Tail left out of the robust range R_rob at each end."""

    velocity_quantile: float = 0.99
    """Velocity out of range: |v − median v| > ``velocity_c`` ×
    q_{velocity_quantile}(|v − median v|) (a measured ``velocity`` only)."""

    velocity_c: float = 4.0
    """Multiple of the ``velocity_quantile`` deviation that is out of range."""

    agree_c: float = 8.0
    """Device tests with a measured displacement *and* velocity: a run of
    jump or out-of-range samples in either is physics, not a fault, when the
    two channels agree across it — the change over the run (± ``spike_reach``
    samples) of e = x − ∫v dt is within ``agree_c`` × its robust SD over every
    window of that length in the record (at least ``spike_floor`` · R_rob of
    the displacement). A fast but consistent transient (a step test's ramp, a
    hard start) is then kept; a velocity that steps or rings on its own is not."""

    end_fraction: float = 0.05
    """End-of-test disturbance: searched in the last ``end_fraction`` of the
    record …"""

    end_c: float = 2.0
    """… a sample whose |Δx| exceeds ``end_c`` × the largest |Δx| before that
    part, or (except displacement, which may end a test offset) whose
    |x − median| exceeds ``end_c`` × the largest one before, in any assessed
    channel, or a jump by the jump test …"""

    end_min_events: int = 2
    """… counted over all channels; with at least ``end_min_events`` such
    samples (a jump *and* its ringing) everything from the first one to the
    end of the record is masked."""

    dilate: int = 3
    """Samples masked on either side of every fault (the edges of a fault are
    rarely clean)."""

    noise_guard: bool = True
    """Skip the rail and flat-line tests on channels whose median
    |second difference| is exactly zero (piecewise-linear or held
    noise-free signals, where repeated values are the signal)."""

    repair: bool = True
    """Repair input channels across their own faults (:func:`apply_quality`)."""

    def __post_init__(self) -> None:
        if self.channels is not None:
            object.__setattr__(self, "channels", tuple(self.channels))

