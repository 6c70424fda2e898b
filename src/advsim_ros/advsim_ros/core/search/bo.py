"""Bayesian optimisation: a BoTorch SingleTaskGP with the GP-UCB acquisition (beta 3).

The first `initial_points` queries are uniform in the box (one batch). After that, each
query maximises UCB(x) = mu(x) + sqrt(beta) sigma(x) (BoTorch's convention) of a GP fitted
to every query so far (inputs mapped to the unit cube, outcomes standardised). Failed
queries enter the GP as the worst value seen.

With `batch_size` q > 1 (evaluation lanes: `advsim attack --lanes`), each batch after the
initial design is q points chosen greedily one after another, each maximising BoTorch's
Monte-Carlo qUpperConfidenceBound with the points already chosen as pending (so the batch
spreads out instead of repeating the UCB maximum); the Monte-Carlo base samples are seeded
from the search's generator. q = 1 is the paper's sequential GP-UCB, unchanged.

Cost per query (the search overhead, not the stack's) is kept low on a 2-core machine:
- torch runs single-threaded inside the fit and the acquisition optimisation (its
  default thread pool oversubscribes 2 cores and made a 75-point fit 5-10x slower);
- the GP hyper-parameters are fitted in full (L-BFGS-B, at most `fit_iterations`) after
  the initial design (and every `full_refit_every` queries when set); otherwise the previous
  values warm-start a short fit of at most `refit_iterations` L-BFGS-B iterations;
- the acquisition is maximised from the best of `raw_samples` candidates (uniform, plus
  Gaussian perturbations of the best queries so far), refined by `num_restarts` short
  L-BFGS-B runs (BoTorch's optimize_acqf).
Every random number comes from the search's numpy Generator; torch's global generator is
left untouched.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from botorch.acquisition.acquisition import AcquisitionFunction
from botorch.acquisition.analytic import UpperConfidenceBound
from botorch.acquisition.monte_carlo import qUpperConfidenceBound
from botorch.exceptions.warnings import InputDataWarning, OptimizationWarning
from botorch.models import SingleTaskGP
from botorch.models.transforms import Standardize
from botorch.optim.fit import fit_gpytorch_mll_scipy
from botorch.optim.optimize import optimize_acqf
from botorch.sampling.normal import SobolQMCNormalSampler
from gpytorch.mlls import ExactMarginalLogLikelihood

from advsim_ros.core.search.base import (
    LOWER_BOUND,
    UPPER_BOUND,
    SearchAlgorithm,
    SearchConfig,
    project_to_box,
    require_config,
)
from advsim_ros.core.types import FloatArray


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


@contextmanager
def _torch_threads(count: int) -> Iterator[None]:
    """Run torch with `count` intra-op threads, restoring the previous setting afterwards."""
    previous = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


class BayesianOptimization(SearchAlgorithm[BoConfig]):
    """GP-UCB, `batch_size` queries per batch after the initial design."""

    name = "bo"

    def __init__(self, config: BoConfig, dimension: int, rng: np.random.Generator) -> None:
        super().__init__(config, dimension, rng)
        self._model: SingleTaskGP | None = None  # the fitted GP, None during the initial design
        self._hyperparameters: dict[str, Any] | None = None  # last fitted values, for warm starts
        self._points_seen: FloatArray = np.empty((0, dimension))
        self._values_seen: FloatArray = np.empty(0)

    def _propose(self) -> FloatArray:
        if self._model is None:
            count = min(self.config.initial_points, self.config.max_queries)
            return self.rng.uniform(LOWER_BOUND, UPPER_BOUND, size=(count, self.dimension))
        with _torch_threads(self.config.torch_threads):
            if self.config.batch_size == 1:
                return self._maximise_acquisition(UpperConfidenceBound(self._model, beta=self.config.beta))[None, :]
            return self._greedy_batch(self._model)

    def _greedy_batch(self, model: SingleTaskGP) -> FloatArray:
        """q points, each maximising qUCB given the ones chosen before it (pending)."""
        chosen: list[FloatArray] = []
        for _ in range(self.config.batch_size):
            sampler = SobolQMCNormalSampler(
                sample_shape=torch.Size([self.config.mc_samples]), seed=int(self.rng.integers(2**31))
            )
            pending = (
                torch.as_tensor((np.array(chosen) - LOWER_BOUND) / (UPPER_BOUND - LOWER_BOUND)) if chosen else None
            )
            acquisition = qUpperConfidenceBound(model, beta=self.config.beta, sampler=sampler, X_pending=pending)
            chosen.append(self._maximise_acquisition(acquisition))
        return np.array(chosen)

    def _observe(self, points: FloatArray, values: FloatArray) -> None:
        self._points_seen = np.concatenate([self._points_seen, points])
        self._values_seen = np.concatenate([self._values_seen, values])
        with _torch_threads(self.config.torch_threads):
            self._fit()

    def _fit(self) -> None:

        inputs = torch.as_tensor((self._points_seen - LOWER_BOUND) / (UPPER_BOUND - LOWER_BOUND))
        outputs = torch.as_tensor(self._values_seen)[:, None]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InputDataWarning)  # flat values (all equal) are valid data here
            model = SingleTaskGP(inputs, outputs, outcome_transform=Standardize(m=1))
        every = self.config.full_refit_every
        full = self._hyperparameters is None or (every > 0 and self._points_seen.shape[0] % every == 0)
        if self._hyperparameters is not None:
            model.load_state_dict(self._hyperparameters, strict=False)
        likelihood = ExactMarginalLogLikelihood(model.likelihood, model)
        likelihood.train()
        options = {"maxiter": self.config.fit_iterations if full else self.config.refit_iterations}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OptimizationWarning)  # "iteration limit reached" is intended in a short fit
            fit_gpytorch_mll_scipy(likelihood, options=options)
        likelihood.eval()
        self._hyperparameters = {
            key: value.detach().clone()
            for key, value in model.state_dict().items()
            if not key.startswith("outcome_transform")
        }
        self._model = model

    def _maximise_acquisition(self, acquisition: AcquisitionFunction) -> FloatArray:

        config = self.config
        local_count = round(config.raw_samples * config.local_fraction)
        uniform = self.rng.uniform(LOWER_BOUND, UPPER_BOUND, size=(config.raw_samples - local_count, self.dimension))
        best = self._points_seen[np.argsort(self._values_seen)[::-1][: max(1, min(5, self._values_seen.size))]]
        centres = best[self.rng.integers(0, best.shape[0], size=local_count)]
        local = project_to_box(centres + config.local_scale * self.rng.standard_normal((local_count, self.dimension)))
        candidates = np.concatenate([uniform, local])
        unit = torch.as_tensor((candidates - LOWER_BOUND) / (UPPER_BOUND - LOWER_BOUND))[:, None, :]
        with torch.no_grad():
            scores = acquisition(unit)
        starts = unit[torch.topk(scores, k=min(config.num_restarts, unit.shape[0])).indices]
        if config.acquisition_iterations == 0:
            return project_to_box(LOWER_BOUND + (UPPER_BOUND - LOWER_BOUND) * starts[0, 0].numpy())
        bounds = torch.stack([torch.zeros(self.dimension), torch.ones(self.dimension)]).to(unit)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OptimizationWarning)  # iteration limit of the short L-BFGS-B runs
            best_unit, _ = optimize_acqf(
                acquisition,
                bounds=bounds,
                q=1,
                num_restarts=starts.shape[0],
                batch_initial_conditions=starts,
                options={"maxiter": config.acquisition_iterations},
                retry_on_optimization_warning=False,
            )
        point = LOWER_BOUND + (UPPER_BOUND - LOWER_BOUND) * best_unit.detach().numpy().reshape(self.dimension)
        return project_to_box(point)
