"""The user-error family: what `advsim` prints as one line (light to import: no numpy)."""

from __future__ import annotations


class UserError(Exception):
    """Something the user can act on (an input, a parameter, a path, a stack that will not start): the message
    names the problem, and `advsim` prints it as one line without a traceback. Every other exception is a bug
    and keeps its traceback. The package's own errors derive from it: ScenarioError (a ValueError) and its kin
    (BagError, ContractError, ResimError, ParamsError, CampaignError, ...), CommandError, LaunchError."""
