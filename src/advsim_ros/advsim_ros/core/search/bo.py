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

from advsim_ros.core.search.base import LOWER_BOUND, UPPER_BOUND, SearchAlgorithm, project_to_box
from advsim_ros.core.search.bo_config import BoConfig
from advsim_ros.core.types import FloatArray


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
