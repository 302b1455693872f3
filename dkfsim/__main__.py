"""``python -m dkfsim`` is the ``dkfsim`` command."""

import sys

from dkfsim.cli.main import main

sys.exit(main())
