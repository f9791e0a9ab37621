"""Layer 4, the sparse QP: its layout (:mod:`.layout`), the fixed-pattern QP updated in
place (:mod:`.sparse`) and its backends (:mod:`.backend`, :mod:`.piqp`, :mod:`.daqp`).
"""

from __future__ import annotations

__all__: list[str] = []
