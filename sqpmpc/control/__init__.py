"""Layer 7, the controllers: settings (:mod:`.settings`), the per-sample pipeline
(:mod:`.pipeline`), the schemes (:mod:`.centralized`, :mod:`.decentralized`) and the
exchanged plans (:mod:`.plans`).
"""

from __future__ import annotations

__all__: list[str] = []
