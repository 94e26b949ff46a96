"""What quality control found: :class:`Fault`, :class:`Repair` and the :class:`QualityReport` of a record."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from bayes_mr.data.quality.config import QualityConfig

#: Fault kinds in report order.
FAULT_KINDS = ("nonfinite", "clipped", "flat", "spike", "jump", "velocity_range", "end_disturbance")


@dataclass(frozen=True)
class Fault:
    """One fault kind found in one channel.

    Attributes
    ----------
    channel : str
        Channel the fault is in.
    kind : str
        One of :data:`FAULT_KINDS`.
    detected : int
        Samples that met the criterion.
    count : int
        Samples masked for it (with dilation).
    ranges : tuple of (start, stop)
        Masked sample ranges, ``start`` inclusive, ``stop`` exclusive.
    threshold : float
        The threshold that was exceeded (channel units, or samples for runs).
    reason : str
        The criterion in words.
    """

    channel: str
    kind: str
    detected: int
    count: int
    ranges: tuple[tuple[int, int], ...]
    threshold: float
    reason: str


@dataclass(frozen=True)
class Repair:
    """Input samples replaced by linear interpolation across a masked run."""

    channel: str
    count: int
    ranges: tuple[tuple[int, int], ...]
    method: str = "linear interpolation between the nearest valid samples (held value at the ends)"


@dataclass(frozen=True)
class QualityReport:
    """What quality control masked and repaired in one record, and why.

    Attributes
    ----------
    source : str
        Where the record came from (its ``source`` attribute).
    n_samples : int
        Length of the record [samples].
    masked : int
        Samples masked by this assessment.
    faults : tuple of Fault
    repaired : tuple of Repair
    channels : tuple of str
        Channels assessed.
    config : QualityConfig
    dt : float
        Sample interval [s] (for ranges in seconds).
    """

    source: str
    n_samples: int
    masked: int
    faults: tuple[Fault, ...] = ()
    repaired: tuple[Repair, ...] = ()
    channels: tuple[str, ...] = ()
    config: QualityConfig = field(default_factory=QualityConfig)
    dt: float = 1.0

    def count(self, channel: str | None = None, kind: str | None = None) -> int:
        """Masked samples of the faults matching ``channel`` and ``kind`` (union)."""
        mask = np.zeros(self.n_samples, bool)
        for f in self.faults:
            if (channel is None or f.channel == channel) and (kind is None or f.kind == kind):
                for a, b in f.ranges:
                    mask[a:b] = True
        return int(mask.sum())

    def to_dict(self) -> dict:
        """JSON-able dict: ``{"masked", "faults": {channel: {kind: {...}}}, "repaired", ...}``."""
        faults: dict[str, dict[str, dict]] = {}
        for f in self.faults:
            faults.setdefault(f.channel, {})[f.kind] = {
                "detected": f.detected,
                "masked": f.count,
                "ranges": [[a, b] for a, b in f.ranges],
                "seconds": [[round(a * self.dt, 6), round(b * self.dt, 6)] for a, b in f.ranges],
                "threshold": float(f.threshold),
                "reason": f.reason,
            }
        repaired = {
            r.channel: {"samples": r.count, "ranges": [[a, b] for a, b in r.ranges], "method": r.method}
            for r in self.repaired
        }
        return {
            "source": self.source,
            "n_samples": self.n_samples,
            "masked": self.masked,
            "masked_fraction": self.masked / self.n_samples if self.n_samples else 0.0,
            "channels": list(self.channels),
            "faults": faults,
            "repaired": repaired,
            "config": asdict(self.config),
        }

    def summary(self) -> str:
        """One paragraph of plain text: what was masked, where and why, and what was repaired."""
        if not self.faults:
            return (
                f"{self.source}: quality control found no faults in "
                f"{', '.join(self.channels) or 'no channels'} ({self.n_samples} samples); nothing masked."
            )
        parts = []
        for f in self.faults:
            first = f.ranges[0]
            where = f"{len(f.ranges)} run(s) from {first[0] * self.dt:.3f} s"
            parts.append(f"{f.channel} {f.kind.replace('_', ' ')}: {f.detected} samples ({where}; {f.reason})")
        text = (
            f"{self.source}: {self.masked} of {self.n_samples} samples masked "
            f"({100 * self.masked / self.n_samples:.2f} %) — " + "; ".join(parts) + "."
        )
        if self.repaired:
            text += " Repaired inputs by linear interpolation: " + ", ".join(
                f"{r.channel} ({r.count} samples)" for r in self.repaired
            ) + "."
        return text

