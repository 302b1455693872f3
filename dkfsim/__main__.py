"""``python -m dkfsim`` is the ``dkfsim`` command."""

import sys

from .cli import main

sys.exit(main())
