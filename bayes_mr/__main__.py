"""``python -m bayes_mr``: the ``bayes-mr`` command."""

import sys

from bayes_mr.cli import main

sys.exit(main())
