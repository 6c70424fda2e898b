"""The settings of Bayesian optimisation (core.search.bo), apart from it so that reading and
checking them (`advsim attack`'s pre-launch notes, campaigns) does not import torch and BoTorch."""

from __future__ import annotations

from dataclasses import dataclass

from advsim_ros.core.search.base import SearchConfig, require_config


@dataclass(frozen=True)
class BoConfig(SearchConfig):
    """GP-UCB with the paper's beta 3, 75 queries, 20 initial points."""

    max_queries: int = 75  # query budget [queries]
    initial_points: int = 20  # uniform initial design before the GP is used [queries]
    beta: float = 3.0  # UCB exploration weight: mu + sqrt(beta) * sigma [1]
    fit_iterations: int = 60  # L-BFGS-B iteration cap of a full hyper-parameter fit [1]
    full_refit_every: int = 0  # also fit to convergence every this many queries; 0: only after the initial design
    refit_iterations: int = 10  # L-BFGS-B iterations of the warm-started fits in between [1]
    raw_samples: int = 512  # acquisition candidates scored before the gradient search [1]
    local_fraction: float = 0.5  # share of the candidates drawn around the best queries so far [1]
    local_scale: float = 0.2  # standard deviation of those local candidates, in box half-widths [1]
    num_restarts: int = 1  # L-BFGS-B runs on the acquisition from the best candidates [1]
    acquisition_iterations: int = 10  # L-BFGS-B iterations per run; 0: take the best candidate as it is [1]
    torch_threads: int = 1  # torch intra-op threads during fits (more is slower on 2 cores) [1]
    batch_size: int = 1  # queries proposed together after the initial design (qUCB when > 1) [queries]
    mc_samples: int = 128  # Monte-Carlo samples of qUCB (batch_size > 1) [1]

    def __post_init__(self) -> None:
        super().__post_init__()
        name = type(self).__name__
        require_config(self.initial_points >= 2, name, "initial_points", "must be at least 2 (a GP needs data)")
        require_config(self.beta >= 0.0, name, "beta", "must be non-negative")
        require_config(self.fit_iterations >= 1, name, "fit_iterations", "must be at least 1")
        require_config(self.full_refit_every >= 0, name, "full_refit_every", "must be non-negative")
        require_config(self.refit_iterations >= 1, name, "refit_iterations", "must be at least 1")
        require_config(self.raw_samples >= 1, name, "raw_samples", "must be at least 1")
        require_config(0.0 <= self.local_fraction <= 1.0, name, "local_fraction", "must be in [0, 1]")
        require_config(self.local_scale > 0.0, name, "local_scale", "must be positive")
        require_config(self.num_restarts >= 1, name, "num_restarts", "must be at least 1")
        require_config(self.acquisition_iterations >= 0, name, "acquisition_iterations", "must be non-negative")
        require_config(self.torch_threads >= 1, name, "torch_threads", "must be at least 1")
        require_config(self.batch_size >= 1, name, "batch_size", "must be at least 1")
        require_config(self.mc_samples >= 1, name, "mc_samples", "must be at least 1")

    def notes(self) -> tuple[str, ...]:
        if self.initial_points < self.max_queries:
            return ()
        # the GP is only fitted after the initial design: a budget it fills is random search, whatever the name
        fewer = max(2, self.max_queries * 2 // 5)
        return (
            f"the initial design of {self.initial_points} uniform queries takes the whole budget of "
            f"{self.max_queries}: no GP-UCB query runs (this is random search); for BO proper set "
            f"search.bo.initial_points below it, e.g. {fewer} (advsim attack --param search.bo.initial_points={fewer}; "
            f"a campaign's parameters: {{search: {{bo: {{initial_points: {fewer}}}}}}})",
        )
