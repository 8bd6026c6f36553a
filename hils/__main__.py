"""``python -m hils``: the same as the ``hils`` command."""

import sys

from hils.cli.main import main

sys.exit(main())
