"""``python -m cvsflow.cli``: the ``cvsflow`` command."""

import sys

from cvsflow.cli import main

sys.exit(main())
