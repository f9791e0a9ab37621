"""Layer 6, the liveness rules: the interface (:mod:`.base`), the built-ins
(:mod:`.liveness`, :mod:`.roundabout`) and the registry (:mod:`.registry`).
"""

from __future__ import annotations

__all__: list[str] = []
