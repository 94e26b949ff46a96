"""Several records of one device: a test matrix, read from a list of files or a manifest CSV.

A damper is characterised by a *test matrix* — sine tests at several
amplitudes, frequencies and constant coil currents — not by one record. A
:class:`RecordSet` holds the records of such a matrix with the conditions each
was run under, so that one likelihood can be summed over them
(:class:`bayes_mr.likelihood.joint.JointLikelihood`).

A **manifest** is a CSV with a header row and one row per record:

* ``file`` (required): the record's path, relative to the manifest's folder;
* ``current`` [A] or ``voltage`` [V] (optional, a unit in brackets allowed,
  ``current [mA]``): the constant command the test ran at;
* ``role`` (optional): ``train`` or ``test`` (empty: ``train``);
* any other column (``temperature [°C]``, ``amplitude [mm]``, …): a condition
  of that test, kept as a number where it reads as one, else as text.

A constant command becomes the record's command channel when the file has
none (:func:`with_constant_command`), so a constant-current matrix informs the
current laws of ``spencer`` and ``voltage_dependence``. Where it comes from,
first found first: the file's own ``current``/``voltage`` column, the
manifest's cell, ``--set current=0.5`` (every file), a ``current``/``voltage``
attribute of a netCDF record.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from bayes_mr.data.schema import COMMANDS, UNITS, Where, command_of
from bayes_mr.data.units import factor, split_header

#: Values of a manifest's ``role`` column.
ROLES = ("train", "test")
#: Columns of a manifest that are not conditions.
MANIFEST_KEYS = ("file", "role")


@dataclass(frozen=True)
class RecordSet:
    """The records of one device's test matrix, with each test's conditions.

    Attributes
    ----------
    records : tuple of xarray.Dataset
        Records in the package schema (:mod:`bayes_mr.data.schema`), all of one kind.
    conditions : tuple of dict
        Per record: condition name → value (``current`` [A], ``voltage`` [V],
        others in the manifest's units), as the manifest or ``--set`` gave them.
    roles : tuple of str
        Per record: ``train`` or ``test`` (:data:`ROLES`).
    source : str
        The manifest's path, or "" for a list of files.
    units : dict
        Condition name → the unit the manifest's header gave it ("" for none).
    record_offsets : bool
        Each test carries its own constant force offset (a load cell zeroed before each test, a preload set
        per test): a likelihood of the set estimates one ``f0[r]`` per record
        (:class:`bayes_mr.likelihood.joint.JointLikelihood`) and a prediction of a record profiles its own.
    """

    records: tuple[xr.Dataset, ...]
    conditions: tuple[dict, ...] = ()
    roles: tuple[str, ...] = ()
    source: str = ""
    units: dict = field(default_factory=dict)
    record_offsets: bool = False

    def __post_init__(self):
        records = tuple(self.records)
        if not records:
            raise ValueError(f"{self.source or 'record set'}: no records — give at least one file")
        kinds = {r.attrs["kind"] for r in records}
        if len(kinds) > 1:
            raise ValueError(f"{self.source or 'record set'}: records of different kinds ({', '.join(sorted(kinds))}) "
                             "— one likelihood sums records of one kind of test")
        object.__setattr__(self, "records", records)
        object.__setattr__(self, "conditions", tuple(self.conditions) or tuple({} for _ in records))
        object.__setattr__(self, "roles", tuple(self.roles) or ("train",) * len(records))
        if not len(self.conditions) == len(self.roles) == len(records):
            raise ValueError("a RecordSet needs one conditions dict and one role per record")

    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self):
        return iter(self.records)

    def __getitem__(self, i: int) -> xr.Dataset:
        return self.records[i]

    @property
    def kind(self) -> str:
        """The records' kind of test (``device``, ``structure`` or ``forced``)."""
        return self.records[0].attrs["kind"]

    @property
    def files(self) -> tuple[str, ...]:
        """Each record's ``source`` attribute (its file)."""
        return tuple(str(r.attrs.get("source", "")) for r in self.records)

    def role(self, role: str) -> "RecordSet":
        """The records of one role (``train`` or ``test``), conditions kept.

        Raises
        ------
        ValueError
            No record has that role.
        """
        keep = [i for i, r in enumerate(self.roles) if r == role]
        if not keep:
            raise ValueError(f"{self.source or 'record set'}: no record has role '{role}'")
        return RecordSet(tuple(self.records[i] for i in keep), tuple(self.conditions[i] for i in keep),
                         tuple(role for _ in keep), self.source, self.units, self.record_offsets)

    def split(self) -> tuple["RecordSet", "RecordSet | None"]:
        """(the ``train`` records, the ``test`` records or None): what a fit fits and what it predicts.

        Raises
        ------
        ValueError
            Every record is a ``test`` record: there is nothing to fit.
        """
        test = self.role("test") if "test" in self.roles else None
        return self.role("train"), test

    def describe(self) -> list[dict]:
        """Per record: ``file``, ``role``, its ``conditions`` and, where the manifest's header gave them, the
        ``units`` of conditions other than the command (which is in A or V) (JSON-ready)."""
        out = []
        for f, r, c in zip(self.files, self.roles, self.conditions):
            entry = {"file": f, "role": r, "conditions": dict(c)}
            units = {k: u for k, u in self.units.items() if u and k in c and k not in COMMANDS}
            out.append({**entry, "units": units} if units else entry)
        return out


def is_manifest(path: str | os.PathLike) -> bool:
    """True when ``path`` is a plain CSV whose header has a ``file`` column and no ``time`` column."""
    path = Path(path)
    if path.suffix.lower() != ".csv" or not path.is_file():
        return False
    with open(path, newline="", encoding="utf-8-sig") as fh:
        header = next(csv.reader(fh), [])
    names = [split_header(h)[0].strip().lower() for h in header]
    return "file" in names and "time" not in names


@dataclass(frozen=True)
class ManifestRow:
    """One row of a manifest: the record's path, its conditions and role; ``line`` is the CSV line (header = 1)."""

    path: Path
    conditions: dict
    role: str
    line: int


def read_manifest(path: str | os.PathLike) -> tuple[list[ManifestRow], dict[str, str]]:
    """The rows of a manifest CSV (module docstring) and the unit of each condition column.

    Returns
    -------
    rows : list of ManifestRow
        Paths resolved against the manifest's folder; ``current``/``voltage`` in A/V.
    units : dict
        Condition name → unit as the header gave it ("" for none).

    Raises
    ------
    RecordError
        One line naming the manifest, its column and line, and what to do: no ``file``
        column, an empty or missing file, a command that is not a number, an unknown role.
    """
    path = Path(path)
    src = str(path)
    with open(path, newline="", encoding="utf-8-sig") as fh:
        table = list(csv.reader(fh))
    if not table:
        raise Where(src).error("empty manifest", "a manifest's header has a 'file' column, then one row per record")
    header = [split_header(h) for h in table[0]]
    names = [n.strip().lower() for n, _ in header]
    if "file" not in names:
        raise Where(src, "file").error("a manifest needs a 'file' column",
                                       "name the records' paths (relative to the manifest) in a column 'file'")
    units = {n: (u or "") for n, u in zip(names, (u for _, u in header)) if n not in MANIFEST_KEYS}
    rows = []
    for line, cells in enumerate(table[1:], start=2):
        if not any(c.strip() for c in cells):
            continue  # a blank line is not a record
        if len(cells) != len(names):
            raise Where(src, row=line).error(f"{len(cells)} cells for {len(names)} columns",
                                             "give every row one cell per header column")
        row = dict(zip(names, (c.strip() for c in cells)))
        rows.append(_manifest_row(src, path.parent, row, units, line))
    if not rows:
        raise Where(src).error("no records listed", "add one row per record below the header")
    return rows, units


def _manifest_row(src: str, folder: Path, row: dict, units: dict, line: int) -> ManifestRow:
    """One manifest row checked: the file exists, the command is a number in A or V, the role is known."""
    if not row["file"]:
        raise Where(src, "file", line).error("empty file name", "give the record's path relative to the manifest")
    file = (folder / row["file"]).resolve() if not Path(row["file"]).is_absolute() else Path(row["file"])
    if not file.exists():
        raise Where(src, "file", line).error(f"no such file '{row['file']}'",
                                             f"paths are relative to the manifest's folder ({folder.resolve()})")
    role = row.get("role", "") or "train"
    if role not in ROLES:
        raise Where(src, "role", line).error(f"unknown role '{role}'", f"valid roles: {', '.join(ROLES)} (empty: train)")
    conditions = {}
    for name, value in row.items():
        if name in MANIFEST_KEYS or value == "":
            continue
        try:
            number = float(value)
        except ValueError:
            if name in COMMANDS:
                raise Where(src, name, line).error(f"'{value}' is not a number",
                                                   f"give the constant {name} in {UNITS[name]} (or leave it empty)") from None
            conditions[name] = value
            continue
        if name in COMMANDS:
            number *= factor(name, units.get(name) or None, Where(src, name, line))
        conditions[name] = number
    if sum(c in conditions for c in COMMANDS) > 1:
        raise Where(src, "current", line).error("a test ran at a constant current or voltage, not both",
                                                "leave one of the two cells empty")
    return ManifestRow(file, conditions, role, line)


def with_constant_command(record: xr.Dataset, conditions: Mapping[str, float]) -> xr.Dataset:
    """The record with a constant command channel from its conditions, when it has no command of its own.

    Parameters
    ----------
    record : xarray.Dataset
        A record after quality control (a constant channel is not a fault to mask).
    conditions : mapping
        ``current`` [A] or ``voltage`` [V] (others ignored); else the record's
        own ``current``/``voltage`` attribute (a netCDF written with one).

    Returns
    -------
    xarray.Dataset
        The record, with ``command_from = "condition"`` when the channel was added.
    """
    if command_of(record) is not None:
        return record
    name = next((c for c in COMMANDS if c in conditions), None)
    value = conditions[name] if name else None
    if name is None:
        name = next((c for c in COMMANDS if isinstance(record.attrs.get(c), (int, float, np.number))), None)
        value = record.attrs.get(name) if name else None
    if name is None:
        return record
    out = record.assign({name: ("time", np.full(record.sizes["time"], float(value)), {"units": UNITS[name]})})
    out.attrs["command_from"] = "condition"
    return out


def load_records(
    sources: str | os.PathLike | Iterable[str | os.PathLike],
    *,
    constants: Mapping[str, float] | None = None,
    **options,
) -> RecordSet:
    """Read several records (a list of files, or one manifest CSV) into a :class:`RecordSet`.

    Parameters
    ----------
    sources : path or iterable of paths
        Record files (any format :func:`bayes_mr.data.load` reads), or one manifest (module docstring).
    constants : mapping, optional
        Conditions of every file (``--set current=0.5``), where the manifest has none.
    **options
        Reading options of :func:`bayes_mr.data.load` (``mass``, ``units``, ``quality``, …), the same for every file.

    Returns
    -------
    RecordSet

    Raises
    ------
    RecordError
        A bad manifest or record: one line naming file, column and row.
    """
    from bayes_mr.data.load import load

    paths = [sources] if isinstance(sources, (str, os.PathLike)) else list(sources)
    if len(paths) == 1 and is_manifest(paths[0]):
        rows, units = read_manifest(paths[0])
        source = str(paths[0])
    else:
        for p in paths:
            if is_manifest(p):
                raise Where(str(p)).error("a manifest among record files",
                                          "give either one manifest or a list of record files")
        rows = [ManifestRow(Path(p), {}, "train", 0) for p in paths]
        units, source = {}, ""
    constants = dict(constants or {})
    records, conditions = [], []
    for row in rows:
        cond = {**constants, **row.conditions} if not any(c in row.conditions for c in COMMANDS) else \
            {**{k: v for k, v in constants.items() if k not in COMMANDS}, **row.conditions}
        records.append(with_constant_command(load(row.path, **options), cond))
        conditions.append(cond)
    return RecordSet(tuple(records), tuple(conditions), tuple(r.role for r in rows), source, units)
