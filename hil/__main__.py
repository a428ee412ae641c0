"""`python -m hil`: the `hil` command line (the same entry point as the console script)."""

import sys

from hil.entry import main  # exit signals set before hil.cli loads

sys.exit(main())
