"""Read the channels of a MATLAB ``.mat`` or HDF5 (``.h5``/``.hdf5``) record, and map lab names to schema names.

Lab files name their variables as the lab does (``t``, ``D``, ``F``); a
column mapping (``columns={"time": "t", "displacement": "D"}``, on the command
line ``--columns time=t,displacement=D``) says which variable is which
channel. Without a mapping, variables named like schema channels are taken.
Other variables (metadata, strings, matrices) are ignored. MATLAB v5 files are
read by :func:`scipy.io.loadmat`, v7.3 files (HDF5 inside) and HDF5 files by
:mod:`h5py`; struct fields and HDF5 groups are named by their path
(``data.t``, ``run1/force``). Units: an HDF5 ``units`` attribute, else the
unit option, else SI. Errors name the file, the channel with its variable and
the sample (index from 0).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from bayes_mr.data import units as _units
from bayes_mr.data.checks import check_columns, check_overrides, one_line
from bayes_mr.data.schema import MIN_SAMPLES, UNITS, Where

ARRAY_SUFFIXES = (".mat", ".h5", ".hdf5")


def parse_columns(options: Mapping[str, str] | Iterable[str] | str | None) -> dict[str, str]:
    """Column mapping schema name → file name from a mapping, ``"time=t,force=F"`` or a list of such strings.

    Raises
    ------
    ValueError
        An item is not ``CHANNEL=NAME``, names an unknown channel, or repeats one.
    """
    if options is None:
        return {}
    if isinstance(options, Mapping):
        items = [f"{k}={v}" for k, v in options.items()]
    else:
        items = [part for opt in ([options] if isinstance(options, str) else options) for part in opt.split(",")]
    out: dict[str, str] = {}
    for item in items:
        name, sep, var = item.partition("=")
        name, var = name.strip(), var.strip()
        if not sep or not name or not var:
            raise ValueError(f"--columns {item.strip()!r}: expected CHANNEL=NAME, e.g. time=t,displacement=D")
        if name not in UNITS:
            raise ValueError(f"--columns {name}={var}: unknown channel '{name}'; channels: {', '.join(UNITS)}")
        if name in out:
            raise ValueError(f"--columns: channel '{name}' given twice")
        out[name] = var
    if len(set(out.values())) < len(out):
        raise ValueError("--columns: one file column mapped to two channels")
    return out


def read_arrays(
    path: Path, src: str, overrides: dict[str, str], columns: dict[str, str]
) -> tuple[np.ndarray, dict[str, np.ndarray], dict, None]:
    """Channels of a ``.mat`` / ``.h5`` record in SI (same return as :func:`~bayes_mr.data.read_csv.read_csv`).

    ``path`` is read, ``src`` names it in messages; ``overrides`` maps a
    channel to its unit (:func:`bayes_mr.data.units.parse_unit_options`) and
    ``columns`` a channel to its variable in the file (:func:`parse_columns`).

    Returns
    -------
    time : ndarray, shape (n,)
        Time stamps [s] as stored.
    channels : dict
        Channel → values in SI.
    attrs : dict
        ``mass`` [kg] if the file holds a scalar variable ``mass``.
    valid : None
    """
    variables, var_units = _variables(path, src)
    chosen = _choose(variables, columns, src)
    check_columns(list(chosen), src, label_row=None)
    check_overrides(overrides, list(chosen), src)
    out: dict[str, np.ndarray] = {}
    n = None
    for name, var in chosen.items():
        where = Where(src, _label(name, var))
        values = _vector(variables[var], where)
        if n is not None and values.size != n:
            raise where.error(f"{values.size} samples where '{_label('time', chosen['time'])}' has {n}",
                              "give every channel the same length")
        n = values.size if n is None else n
        bad = ~np.isfinite(values)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise Where(src, _label(name, var), i, label="sample").error(
                f"{'NaN' if np.isnan(values[i]) else 'infinite'} value", "every sample must be a finite number"
            )
        unit = var_units.get(var)
        if unit is not None and name in overrides:
            raise where.error(f"the file says units '{unit}' but units ask for {overrides[name]}",
                              "drop the units option")
        out[name] = values * _units.factor(name, overrides.get(name, unit), where)
    time = out.pop("time")
    if time.size < MIN_SAMPLES:
        raise Where(src).error(f"only {time.size} samples", f"a record needs at least {MIN_SAMPLES} samples")
    attrs = {}
    mass = variables.get("mass")
    if mass is not None and np.size(mass) == 1 and np.issubdtype(np.asarray(mass).dtype, np.number):
        attrs["mass"] = float(np.asarray(mass).ravel()[0])
    return time, out, attrs, None


def _label(name: str, var: str) -> str:
    """How errors name a channel: the schema name, with the file's variable when they differ."""
    return name if name == var else f"{name}={var}"


def _choose(variables: dict[str, np.ndarray], columns: dict[str, str], src: str) -> dict[str, str]:
    """Channel → variable: the mapping, plus variables named like channels that the mapping leaves free."""
    for name, var in columns.items():
        if var not in variables:
            have = ", ".join(sorted(variables)[:20]) or "none"
            raise Where(src, name).error(f"no variable '{var}' in the file", f"numeric variables: {have}")
    chosen = dict(columns)
    mapped = set(columns.values())
    for var in variables:
        if var in UNITS and var not in chosen and var not in mapped:
            chosen[var] = var
    if "time" not in chosen:
        have = ", ".join(sorted(variables)[:20]) or "none"
        raise Where(src, "time").error(
            "missing column", f"map the file's variables to channels with --columns time=NAME,... (variables: {have})"
        )
    return {"time": chosen.pop("time"), **chosen}


def _vector(a: np.ndarray, where: Where) -> np.ndarray:
    """A variable as a float vector (MATLAB's n×1 and 1×n both accepted)."""
    a = np.asarray(a)
    if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise where.error(f"not a real numeric variable ({a.dtype})", "map a numeric vector to this channel")
    squeezed = np.squeeze(a)
    if squeezed.ndim != 1:
        raise where.error(f"shape {a.shape} is not a vector", "store each channel as an n×1 or 1×n array")
    return squeezed.astype(float)


def _variables(path: Path, src: str) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Numeric variables of the file by name, and the ``units`` attribute of those that have one."""
    import h5py

    try:
        if h5py.is_hdf5(path):  # HDF5 and MATLAB v7.3
            return _hdf5_variables(path)
        return _mat_variables(path), {}
    except Exception as exc:  # noqa: BLE001 — scipy and h5py raise many types on a damaged file
        kind = "MATLAB" if path.suffix.lower() == ".mat" else "HDF5"
        raise Where(src).error(
            f"cannot read as {kind} ({one_line(exc)})", "save it with MATLAB save(..., '-v7') / '-v7.3' or h5py"
        ) from None


def _mat_variables(path: Path) -> dict[str, np.ndarray]:
    from scipy.io import loadmat

    raw = loadmat(path, simplify_cells=True)
    out: dict[str, np.ndarray] = {}
    _flatten({k: v for k, v in raw.items() if not k.startswith("__")}, "", out)
    return out


def _flatten(tree: dict, prefix: str, out: dict[str, np.ndarray]) -> None:
    """Numeric leaves of nested MATLAB structs as ``a.b.c`` → array."""
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            _flatten(value, name + ".", out)
        elif isinstance(value, (int, float, np.number)):
            out[name] = np.asarray(value)
        elif isinstance(value, np.ndarray) and np.issubdtype(value.dtype, np.number):
            out[name] = value


def _hdf5_variables(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    import h5py

    out: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}

    def visit(name: str, obj) -> None:
        if name.startswith("#refs#") or not isinstance(obj, h5py.Dataset):
            return
        if not np.issubdtype(obj.dtype, np.number) or obj.attrs.get("MATLAB_class", b"") in (b"char", b"cell"):
            return
        out[name] = obj[()]
        unit = obj.attrs.get("units")
        if unit is not None:
            units[name] = unit.decode() if isinstance(unit, bytes) else str(unit)

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return out, units
