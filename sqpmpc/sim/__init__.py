"""Layer 8, the closed loop: the run buffer (:mod:`.record`) and the in-process simulation
(:mod:`.simulation`).
"""

from __future__ import annotations

__all__: list[str] = []
