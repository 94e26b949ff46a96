"""The packaged NEES MR-damper record: conversion from the raw file and loading.

The raw file (``ranran_50.csv.gz``, NEES-2012-1158 Experiment 3, see
``resources/PROVENANCE.md``) has columns ``t`` [s], ``A`` (actuator
acceleration, unused), ``D`` piston displacement [cm], ``Y`` command voltage
[V], ``fs`` sampling rate (first row only, 3004.8 Hz), ``V`` piston velocity
[cm/s] (derived by the source), ``F`` damper force [N], and a trailing comma
on every line. Its ``t`` column is rounded further into the record, so time
is rebuilt as ``i / fs``.

Build the packaged file with ``python -m bayes_mr.data.nees RAW OUT``.
"""

from __future__ import annotations

import os
import sys
import tempfile
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from .quality import QualityConfig, apply_quality
from .read import read_file
from .schema import Where
from .write import publish

#: Significant digits written to the packaged CSV: the raw file has at most 8.
DIGITS = 8

#: Packaged records: name → (resource file, attributes).
PACKAGED: dict[str, tuple[str, dict[str, str]]] = {
    "nees-ranran-50": (
        "nees_ranran_50.csv.gz",
        {
            "title": "Prototype MR Damper Characterization Tests Using White Noise "
            "(random displacement, random on/off voltage)",
            "creator": "S. J. Dyke",
            "doi": "10.4231/D3V11VM6X",
            "nees_project": "NEES-2012-1158, Experiment 3",
            "collected": "1994-1996",
            "device": "prototype MR damper (very likely the one modelled by Spencer, Dyke, Sain & Carlson 1997; "
            "not confirmed)",
            "raw_file": "ranran_50.csv.gz",
            "conversion": "time rebuilt as i/3004.8 s; displacement and velocity cm -> m (x 0.01); "
            "force [N] and voltage [V] unchanged; actuator acceleration A dropped; 8 significant digits",
            "notes": "force mean about -124 N is the accumulator preload (a force offset), not a fault; "
            "the voltage is the command to the current driver, not the coil current",
        },
    ),
}

_RAW_COLUMNS = ("t", "A", "D", "Y", "fs", "V", "F")


def convert_nees(raw_path: str | os.PathLike, out_path: str | os.PathLike) -> Path:
    """Convert the raw NEES ``ranran`` CSV to a record CSV in SI units.

    Parameters
    ----------
    raw_path : path
        Raw file (columns ``t, A, D, Y, fs, V, F``; gzip or plain).
    out_path : path
        Output ``.csv`` or ``.csv.gz`` with columns ``time, displacement,
        velocity, voltage, force`` [s, m, m/s, V, N], written atomically.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    RecordError
        Missing file or columns, no sampling rate, a bad cell (line named), or
        an unwritable output; nothing is written.
    """
    raw_path, out_path = Path(raw_path), Path(out_path)
    src = str(raw_path)
    if not raw_path.exists():
        raise Where(src).error("file not found", "check the path to the raw NEES file")
    name = out_path.name.lower()
    if not name.endswith((".csv", ".csv.gz")):
        raise Where(str(out_path)).error("unknown output type", "write .csv or .csv.gz")
    if not out_path.parent.is_dir():
        raise Where(str(out_path)).error("the directory does not exist", "create it first")
    try:
        df = pd.read_csv(raw_path, dtype=str, keep_default_na=False, index_col=False)
    except Exception as exc:  # noqa: BLE001 — gzip / parser errors become one line
        raise Where(src).error(f"cannot read ({' '.join(str(exc).split())[:150]})", "check the raw file") from None
    df.columns = [str(c).strip() for c in df.columns]
    for col in _RAW_COLUMNS:
        if col not in df.columns:
            raise Where(src, col, 1).error("missing column", f"the raw NEES file has columns {', '.join(_RAW_COLUMNS)}")
    data = {}
    for col in ("D", "Y", "V", "F"):
        numeric = pd.to_numeric(df[col].str.strip(), errors="coerce").to_numpy(float)
        bad = ~np.isfinite(numeric)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise Where(src, col, i + 2).error(f"bad value '{df[col].iloc[i]}'", "fix or remove the line")
        data[col] = numeric
    try:
        fs = float(df["fs"].iloc[0])
    except ValueError:
        fs = float("nan")
    if not np.isfinite(fs) or fs <= 0:
        raise Where(src, "fs", 2).error("no sampling rate in the first data row", "the raw file gives fs once, on line 2")
    n = len(df)
    out = pd.DataFrame(
        {
            "time": np.arange(n) / fs,
            "displacement": data["D"] * 1e-2,
            "velocity": data["V"] * 1e-2,
            "voltage": data["Y"],
            "force": data["F"],
        }
    )
    fd, tmp = tempfile.mkstemp(prefix=f".{out_path.name}.", suffix=".tmp", dir=out_path.parent)
    os.close(fd)
    try:
        # time gets more digits: 8 would round it by ~1e-6 s, a few % of dt
        out["time"] = out["time"].map(lambda v: f"{v:.12g}")
        out.to_csv(
            tmp,
            index=False,
            float_format=f"%.{DIGITS}g",
            compression="gzip" if name.endswith(".gz") else None,
        )
        publish(tmp, out_path)
    except Exception as exc:  # noqa: BLE001 — clean up, then one line
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise Where(str(out_path)).error(f"cannot write ({' '.join(str(exc).split())[:150]})", "check the path") from None
    return out_path


def load_packaged(name: str = "nees-ranran-50", quality: bool | QualityConfig = True) -> xr.Dataset:
    """Load a measured record that ships with the package.

    Parameters
    ----------
    name : str
        One of :data:`PACKAGED` (``"nees-ranran-50"``: MR damper, random
        displacement 0–50 Hz, random on/off voltage, 3004.8 Hz, 74,068 samples).
    quality : bool or QualityConfig
        Run quality control on load (see :func:`bayes_mr.data.load`).

    Returns
    -------
    xarray.Dataset
        Device-test record in SI; ``source`` = ``name``; provenance attributes
        (``title``, ``doi``, ``conversion``, …).
    """
    if name not in PACKAGED:
        raise KeyError(f"no packaged record {name!r}; available: {', '.join(PACKAGED)}")
    filename, attrs = PACKAGED[name]
    ref = resources.files("bayes_mr.data").joinpath("resources", filename)
    with resources.as_file(ref) as path:
        ds = read_file(path)
    ds.attrs["source"] = name
    ds.attrs.update(attrs)
    ds["velocity"].attrs["description"] = "piston velocity as supplied by the source (derived there)"
    ds["voltage"].attrs["description"] = "command voltage to the damper's current driver"
    if quality is not False:
        ds = apply_quality(ds, quality if isinstance(quality, QualityConfig) else QualityConfig())
    return ds


def main(argv: list[str] | None = None) -> int:
    """``python -m bayes_mr.data.nees RAW OUT``: build the packaged file."""
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2 or argv[0] in ("-h", "--help"):
        print("usage: python -m bayes_mr.data.nees RAW.csv.gz OUT.csv.gz", file=sys.stderr)
        return 2
    try:
        path = convert_nees(argv[0], argv[1])
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
