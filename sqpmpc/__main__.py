"""``python -m sqpmpc`` is the ``sqpmpc`` command."""

import sys

from .cli import main

sys.exit(main())
