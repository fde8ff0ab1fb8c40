"""``python -m hybridtwin.cli``: the same as the ``hybridtwin`` command."""

import sys

from . import main

sys.exit(main())
