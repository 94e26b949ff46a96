"""Child process that compiles one specialised kernel into the disk cache (``python -m bayes_mr._compile_worker``).

Started by :func:`bayes_mr._specialise._start_background` with the generated
module's path, the kernel's name, a file holding the argument types (pickled,
hex) and the marker to write when numba has saved the machine code: the
parent runs the generic kernel until that marker exists.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    """Compile ``argv`` = [module path, kernel name, types file, marker]; 0 on success."""
    from bayes_mr._specialise import _load, mark_ready

    path, name, types_file, marker = argv
    argtypes = pickle.loads(bytes.fromhex(Path(types_file).read_text()))
    fn = getattr(_load(Path(path)), name)
    fn.compile(argtypes)  # a cached dispatcher saves the overload to numba's cache here
    mark_ready(Path(marker), name, argtypes)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
