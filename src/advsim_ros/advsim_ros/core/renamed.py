"""Names that changed, and the names they read as now (a leaf module: journals and the search registry use it).

The search algorithm SimBA was registered as "rs" before it was "simba". What was recorded under
an old name (attack journals, campaign journals and their results rows) reads as the new name;
a name a user gives is accepted under its old name with a warning (core.search.registry).
"""

from __future__ import annotations

from collections.abc import Mapping

RENAMED_ALGORITHMS: Mapping[str, str] = {"rs": "simba"}  # old name -> its name now


def canonical_algorithm(name: str) -> str:
    """An algorithm name as it is named now: an old name (RENAMED_ALGORITHMS) as its new one, any other unchanged."""
    return RENAMED_ALGORITHMS.get(name, name)
