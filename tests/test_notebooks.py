"""Every notebook in ``notebooks/`` (jupytext percent ``.py`` files) runs top to bottom without error.

Each is converted with jupytext and executed by nbclient in a temporary
working directory. The kernel is this interpreter's ipykernel, whatever
kernels are registered on the machine: a kernelspec pointing at
``sys.executable`` is written to a temporary directory and the kernel
manager looks only there (a ``python3`` kernel in the user's Jupyter
directory, which would otherwise win, can point at another Python). The
first executed cell checks that the kernel runs in this environment.

A notebook's own ``assert`` cells are part of the test: any cell error
(a failed assertion included) fails it, with the cell's traceback.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

jupytext = pytest.importorskip("jupytext")
nbclient = pytest.importorskip("nbclient")
nbformat = pytest.importorskip("nbformat")
from ipykernel.kernelspec import write_kernel_spec  # noqa: E402
from jupyter_client.kernelspec import KernelSpecManager  # noqa: E402
from jupyter_client.manager import KernelManager  # noqa: E402
from nbclient.exceptions import CellExecutionError  # noqa: E402

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.py"))


def kernel_manager(tmp: Path) -> KernelManager:
    """A manager for a ``python3`` kernel running ``sys.executable -m ipykernel_launcher``."""
    kernels = tmp / "kernels"
    kernels.mkdir()
    write_kernel_spec(kernels / "python3")  # argv[0] = sys.executable
    ksm = KernelSpecManager(kernel_dirs=[str(kernels)], ensure_native_kernel=False)
    return KernelManager(kernel_name="python3", kernel_spec_manager=ksm)


def test_notebooks_exist():
    assert NOTEBOOKS, f"no notebooks in {NOTEBOOK_DIR}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path: Path, tmp_path: Path):
    nb = jupytext.read(path)
    check = nbformat.v4.new_code_cell(
        "import sys\n"
        f"assert sys.prefix == {sys.prefix!r}, (sys.executable, sys.prefix)"
    )
    nb.cells.insert(0, check)
    work = tmp_path / "work"
    work.mkdir()
    km = kernel_manager(tmp_path)
    client = nbclient.NotebookClient(
        nb, km=km, timeout=600, kernel_name="python3", allow_errors=False,
        resources={"metadata": {"path": str(work)}},
    )
    try:
        client.execute(cleanup_kc=True)
    except CellExecutionError as err:
        message = re.sub(r"\x1b\[[0-9;]*m", "", str(err))  # the traceback comes with terminal colours
        pytest.fail(f"{path.name}: a cell failed\n{message}", pytrace=False)
    finally:
        if km.has_kernel and km.is_alive():
            km.shutdown_kernel(now=True)
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors, errors
