"""One pair for everything the package produces: :func:`save` and :func:`load`.

=====================================  =========================================  ==========================
what                                   ``save(obj, path)`` writes                 ``load(path)`` returns
=====================================  =========================================  ==========================
a record (``xarray.Dataset``)          CSV, CSV.gz or netCDF by the suffix        the record, read and
                                       (:func:`bayes_mr.data.write_record`)       prepared (:func:`bayes_mr.data.load`)
a fit (``arviz.InferenceData``)        netCDF (:func:`~bayes_mr.inference.        the InferenceData
                                       results.save`)
a :class:`~bayes_mr.selection.result.  ``path`` (JSON of ``to_dict()``) and its   the Comparison, its
Comparison`                            fits in ``<stem>.idata/``                  ``idata`` read back
a :class:`~bayes_mr.diagnosis.result.  ``path`` (JSON of ``to_dict()``) and its   the Diagnosis, its
Diagnosis`                             fits in ``<stem>.idata/``                  ``idata`` read back
=====================================  =========================================  ==========================

A comparison's fits are written one netCDF per (model, engine); their stored
summary names the pair, so the file names only need to be distinct. A
diagnosis's fits are ``baseline.nc``, ``extended.nc`` and (with a kept term)
``terms.nc``. :func:`load` tells a record's netCDF from an InferenceData's
by its groups, and a comparison's JSON from a diagnosis's by its keys.
"""

from __future__ import annotations

import inspect
import json
import os
import shutil
from pathlib import Path

import xarray as xr

from bayes_mr.data import load as read_record
from bayes_mr.data import write_record
from bayes_mr.data.checks import NC_SUFFIXES, file_suffix
from bayes_mr.data.records import is_manifest, load_records
from bayes_mr.diagnosis.result import Diagnosis
from bayes_mr.inference import results
from bayes_mr.selection.result import Comparison

__all__ = ["fits_dir", "load", "save"]


def fits_dir(path: str | os.PathLike) -> Path:
    """Where :func:`save` puts a comparison's or a diagnosis's InferenceData: ``<stem>.idata/`` beside ``path``."""
    path = Path(path)
    return path.with_name(path.name.removesuffix(".json") + ".idata")


def save(obj, path: str | os.PathLike) -> Path:
    """Write a record, an InferenceData, a Comparison or a Diagnosis; :func:`load` reads it back.

    Parameters
    ----------
    obj : xarray.Dataset, arviz.InferenceData, Comparison or Diagnosis
        A record is written by :func:`~bayes_mr.data.write_record` (``.csv``,
        ``.csv.gz`` or ``.nc`` by the suffix), an InferenceData as netCDF; a
        Comparison or Diagnosis as the JSON of its ``to_dict()`` (what the CLI
        writes) at ``path``, with its InferenceData as netCDF files in
        :func:`fits_dir` (replaced whole; none when it has none).
    path : str or path-like

    Returns
    -------
    pathlib.Path
        The path written.
    """
    if isinstance(obj, (Comparison, Diagnosis)):
        return _save_result(obj, Path(path))
    if isinstance(obj, xr.Dataset):
        return write_record(obj, path)
    if hasattr(obj, "groups") and hasattr(obj, "to_netcdf"):  # arviz.InferenceData
        return results.save(obj, path)
    raise TypeError(f"save: cannot write a {type(obj).__name__} (a record, an InferenceData, a Comparison or a "
                    "Diagnosis)")


def load(path: str | os.PathLike, *args, **kwargs):
    """Read what :func:`save` (or the CLI) wrote: a record, an InferenceData, a Comparison or a Diagnosis.

    A record (CSV, CSV.gz, MATLAB, HDF5 or a record's netCDF) is read exactly
    as :func:`bayes_mr.data.load` reads it, with its options (``mass``,
    ``units``, ``columns``, ``quality``, ``trim``, ``velocity``, ``noise_floor``,
    ``noise_record``). A netCDF with a ``posterior`` group is an InferenceData
    (:func:`~bayes_mr.inference.results.load_result`); a ``.json`` is a
    Comparison (``rows``, ``selected``) or a Diagnosis (``baseline``, ``cause``),
    with the InferenceData :func:`save` wrote beside it. Those take no options.

    Several records — a list of paths, or a manifest CSV (a ``file`` column, per-file
    conditions such as ``current [A]``, optional ``role``) — are read with the same options
    into a :class:`~bayes_mr.data.records.RecordSet` (:func:`~bayes_mr.data.records.load_records`;
    ``constants={"current": 0.5}`` gives every file a condition), which ``Identify.fit``,
    ``compare`` and ``validate_records`` take.
    """
    if not isinstance(path, (str, os.PathLike)) or is_manifest(path):
        return load_records(path, *args, **kwargs)
    what = _what(Path(path))
    if what == "record":
        return read_record(path, *args, **kwargs)
    if args or kwargs:
        raise TypeError(f"load: {path} is {what}; the reading options ({', '.join(kwargs) or 'positional'}) "
                        "are a record's")
    if what == "an InferenceData":
        return results.load_result(path)
    return _load_result(Path(path))


load.__signature__ = inspect.signature(read_record)


def _what(path: Path) -> str:
    """``record``, ``an InferenceData`` or ``a result`` (a comparison's or a diagnosis's JSON)."""
    if path.suffix.lower() == ".json":
        return "a result"
    if file_suffix(path) in NC_SUFFIXES and path.is_file():
        try:
            import netCDF4

            with netCDF4.Dataset(path) as nc:
                if "posterior" in nc.groups:
                    return "an InferenceData"
        except (ImportError, OSError):
            pass  # the record reader says what is wrong with the file
    return "record"


def _save_result(obj: Comparison | Diagnosis, path: Path) -> Path:
    fits = fits_dir(path)
    idata = obj.idata
    if fits.exists():
        shutil.rmtree(fits)
    if idata:
        fits.mkdir(parents=True)
        for i, (key, data) in enumerate(idata.items()):
            name = f"{i:02d}__{'__'.join(key).replace('+', '_')}" if isinstance(key, tuple) else str(key)
            results.save(data, fits / f"{name}.nc")
    return results.write_json(obj.to_dict(), path)


def _load_result(path: Path) -> Comparison | Diagnosis:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file — write one with bm.save(result, {str(path)!r})")
    data = json.loads(path.read_text())
    files = sorted(fits_dir(path).glob("*.nc"))
    if {"rows", "selected", "bayes_factors"} <= set(data):
        idata = {}
        for f in files:
            one = results.load_result(f)
            s = results.summary_of(one)
            idata[(s.model, s.engine)] = one
        return Comparison(data, idata)
    if {"baseline", "cause", "extended"} <= set(data):
        return Diagnosis(data, {f.stem: results.load_result(f) for f in files})
    raise ValueError(f"{path}: neither a comparison nor a diagnosis (no rows/selected, no baseline/cause keys)")
