"""Layer 4, coordination by design: the roadmap of the free space (:mod:`.roadmap`),
conflict-free multi-robot plans on it (:mod:`.mapf`, LaCAM with PIBT), their
delay-tolerant execution (:mod:`.schedule`, an action dependency graph) and the
fleet's plan for a scenario (:mod:`.fleet`).
"""

from __future__ import annotations

__all__: list[str] = []
