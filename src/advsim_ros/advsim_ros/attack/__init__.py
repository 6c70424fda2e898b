"""One attack: options, pre-launch checks, the graph run, the journal, the outputs (see attack.run)."""

from advsim_ros.attack.options import AttackError, AttackOptions, StackSpec
from advsim_ros.attack.run import AttackResult, run_attack, search_notes

__all__ = ["AttackError", "AttackOptions", "AttackResult", "StackSpec", "run_attack", "search_notes"]
