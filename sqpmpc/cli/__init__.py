"""Layer 10, the ``sqpmpc`` command (:mod:`.main`) and the options every command shares
(:mod:`.options`).
"""

from __future__ import annotations

from sqpmpc.cli.main import main

__all__ = ["main"]
