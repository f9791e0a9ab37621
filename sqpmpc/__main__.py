"""``python -m sqpmpc`` is the ``sqpmpc`` command."""

import sys

from sqpmpc.cli.main import main

sys.exit(main())
