"""``python -m sqpmpc`` is the ``sqpmpc`` command."""

import sys

from sqpmpc.cli import console

sys.exit(console())
