"""``python -m bench.cli``: the same as the ``whiskerbench`` script."""

import sys

from bench.cli.main import main

sys.exit(main())
