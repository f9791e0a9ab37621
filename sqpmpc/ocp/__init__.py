"""Layer 5, the optimal control problem: the RTI/SQP iteration (:mod:`.iteration`) and the
rows it linearizes (collision rows :mod:`.collision_rows`, obstacle rows
:mod:`.obstacle_rows`, their :mod:`.geometry`).
"""

from __future__ import annotations

__all__: list[str] = []
