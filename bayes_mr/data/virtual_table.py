"""A virtual shake table: a structure test built from a measured damper test.

The thesis identifies its damper models inside a single-storey frame on a
shake table, from displacement and acceleration only, and could only say
its identified damper force was "underestimated by about 2 N". With a
device test (imposed piston motion, measured force) the frame can be built
around the damper by inverse dynamics, so the force is known:

choose a frame (m, c, k); let the storey's displacement relative to the base
be the measured piston displacement x(t); the storey equation
m(ẍ + ẍ_g) + c ẋ + k x + F(t) = 0 with the measured damper force F(t) then
gives the ground acceleration that makes the storey move exactly so:

    ẍ_g = −ẍ − (c ẋ + k x + F)/m,   absolute acceleration a = ẍ + ẍ_g = −(c ẋ + k x + F)/m.

ẋ and ẍ come from a Savitzky–Golay differentiator of the measured
displacement (the same one the package uses for velocity). The record keeps
the measured damper force in ``force``, so identified and measured damper
forces can be compared; an identification uses displacement and
acceleration only, as the thesis did.

An identified structure model lumps the frame's and the damper's linear
terms in its ``c`` and ``k``, and its ``force`` output is only the
hysteretic part of f_r (SPEC). The damper force it implies is what is left
of the whole restoring force once the known frame is taken out,
F̂ = f̂_r − c ẋ̂ − k x̂ with f̂_r = −m â (:func:`implied_damper_force`): that
is the number to hold against the measured force.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from scipy import signal

from bayes_mr.data.derive import bandwidth, savgol_window
from bayes_mr.data.schema import DEVICE, make_record

#: The thesis's frame (§4.3, §5.3): mass [kg], stiffness [N/m], damping [N·s/m].
THESIS_FRAME = {"mass": 27.0, "k": 25_000.0, "c": 100.0}


def virtual_shake_table(
    device: xr.Dataset,
    *,
    mass: float = THESIS_FRAME["mass"],
    k: float = THESIS_FRAME["k"],
    c: float = THESIS_FRAME["c"],
) -> xr.Dataset:
    """Structure test whose storey follows the damper's measured motion.

    Parameters
    ----------
    device : xarray.Dataset
        A device test (displacement [m], force [N], optional voltage [V]).
    mass, k, c : float
        Frame mass [kg], stiffness [N/m] and viscous damping [N·s/m].

    Returns
    -------
    xarray.Dataset
        Structure test with ``ground_acceleration``, ``displacement``,
        ``acceleration``, ``force`` (the measured damper force) and
        ``voltage``; attrs ``frame_mass``, ``frame_k``, ``frame_c`` and the
        source's quality mask carried over.
    """
    if device.attrs.get("kind") != DEVICE:
        raise ValueError("a virtual shake table is built from a device test (displacement and force)")
    dt = float(device.attrs["dt"])
    x = device["displacement"].values
    force = device["force"].values
    window = savgol_window(dt, bandwidth(x, dt), polyorder=4)
    window = min(window, x.size - (1 - x.size % 2))
    xd = signal.savgol_filter(x, window, 4, deriv=1, delta=dt, mode="interp")
    xdd = signal.savgol_filter(x, window, 4, deriv=2, delta=dt, mode="interp")
    restoring = c * xd + k * x + force
    a_abs = -restoring / mass
    channels = {
        "ground_acceleration": a_abs - xdd,
        "displacement": x,
        "acceleration": a_abs,
        "force": force,
    }
    if "voltage" in device:
        channels["voltage"] = device["voltage"].values
    valid = device["valid"].values if "valid" in device else None
    attrs = {
        "frame_mass": float(mass), "frame_k": float(k), "frame_c": float(c),
        "virtual_table": "ground acceleration by inverse dynamics of a frame around the measured damper",
        "savgol_window": int(window),
    }
    for key in ("noise_sd_displacement",):
        if key in device.attrs:
            attrs[key] = device.attrs[key]
    if "noise_sd_force" in device.attrs:
        attrs["noise_sd_acceleration"] = float(device.attrs["noise_sd_force"]) / mass
    return make_record(device["time"].values, channels, kind="structure", mass=mass,
                       source=f"virtual shake table around {device.attrs.get('source', 'device test')}",
                       valid=valid, attrs=attrs)


def implied_damper_force(table: xr.Dataset, predicted: dict[str, np.ndarray]) -> np.ndarray:
    """The damper force a structure model identified on a virtual shake table implies [N].

    Parameters
    ----------
    table : xarray.Dataset
        A record made by :func:`virtual_shake_table` (frame attributes
        ``frame_mass`` [kg], ``frame_k`` [N/m], ``frame_c`` [N·s/m]).
    predicted : dict of str → ndarray, shape (n,)
        Simulated ``displacement`` [m], ``velocity`` [m/s] and absolute
        ``acceleration`` [m/s²] of the identified model on ``table``.

    Returns
    -------
    ndarray, shape (n,)
        F̂ = −m â − c ẋ̂ − k x̂: the whole restoring force of the model less
        the known frame's.
    """
    try:
        m, k, c = (float(table.attrs[key]) for key in ("frame_mass", "frame_k", "frame_c"))
    except KeyError as exc:
        raise ValueError(f"{table.attrs.get('source', 'record')} is not a virtual shake table "
                         f"(no {exc.args[0]} attribute): build it with virtual_shake_table") from None
    return -m * np.asarray(predicted["acceleration"]) - c * np.asarray(predicted["velocity"]) \
        - k * np.asarray(predicted["displacement"])
