"""``python -m whiskerbench``: the same as the ``whiskerbench`` script (and ``-m bench.cli``)."""

import sys

from bench.cli.main import main

sys.exit(main())
