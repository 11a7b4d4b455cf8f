"""What a fitted GP offers its callers, exact (:class:`rbgp_cli.gp.exact.GaussianProcess`) or sparse
(:class:`rbgp_cli.gp.sparse.SparseGP`): the :class:`Posterior` protocol.

The motion model (:class:`rbgp_cli.dynamics.model.MotionModel`), rollouts, model files
(:mod:`rbgp_cli.io.model_store`) and the noise calibration (:mod:`rbgp_cli.gp.calibration`) use a GP
only through these members, so either GP serves them. Checked at run time with ``isinstance`` (the
protocol is ``runtime_checkable``: that tests that the members exist, not their signatures).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from rbgp_cli.kernels.base import Kernel

__all__ = ["Posterior", "PriorOnly"]


@runtime_checkable
class Posterior(Protocol):
    """A fitted GP with L outputs on training inputs X (n, d).

    kernel : the :class:`Kernel` of every output
    X : training inputs, shape (n, d);  Y : training outputs, shape (n, L)
    fits : one :class:`~rbgp_cli.gp.results.OutputFit` per output, or one for all (``shared``)
    shared : one set of hyperparameters for all outputs, on Y / y_scale
    y_scale : shape (L,), each output's scale (root mean square in shared mode, else ones)
    """

    kernel: Kernel
    X: np.ndarray
    Y: np.ndarray
    fits: list
    shared: bool
    y_scale: np.ndarray

    @property
    def n_outputs(self) -> int:
        """L, the number of outputs."""
        ...

    def group_outputs(self) -> list:
        """``[(fit, outputs)]``: each set of hyperparameters with the output columns it serves (one
        pair per output, or one for all of them when ``shared``)."""
        ...

    def predict(self, Xs, return_std: bool = False, noisy: bool = False, chunk_elements: int = 2_000_000,
                manage_threads: bool = True):
        """Predictive mean at query inputs Xs (m, d), shape (m, L), and with ``return_std`` also the
        standard deviation, shape (m, L) (of the latent function, or of a new noisy observation with
        ``noisy``): see :meth:`rbgp_cli.gp.exact.GaussianProcess.predict`."""
        ...

    def predict_mean(self, Xs) -> np.ndarray:
        """Predictive mean, shape (m, L) (single-step mean prediction, docs/method.md §8)."""
        ...


class PriorOnly:
    """A fitted GP with its residual field switched off: every prediction is the GP's prior, mean 0
    and standard deviation √(k(x, x) (+ σn² with ``noisy``)) · scale per output, whatever the
    training data. A motion model whose GP is this follows its prior mean alone (the path
    distribution: the start-conditioned mean path and its pull, docs/method.md §7), which is how
    ``rbgp crossval`` measures what the GP adds (its "without the GP" rows). Every other member
    (kernel, X, Y, fits, …) is the wrapped GP's."""

    def __init__(self, gp: Posterior):
        self._gp = gp

    def __getattr__(self, name):
        return getattr(self._gp, name)

    def predict(self, Xs, return_std: bool = False, noisy: bool = False, chunk_elements: int = 2_000_000,
                manage_threads: bool = True):
        """Mean zeros (m, L); with ``return_std`` the prior standard deviation (m, L)."""
        Xs = np.asarray(Xs, dtype=np.float64).reshape(-1, self._gp.X.shape[1])
        L = self._gp.n_outputs
        mean = np.zeros((len(Xs), L))
        if not return_std:
            return mean
        std = np.empty((len(Xs), L))
        for fit, outs in self._gp.group_outputs():
            var = self._gp.kernel.diag(Xs, fit.values) + ((fit.values["noise_std"] ** 2 + fit.jitter) if noisy else 0.0)
            std[:, outs] = np.sqrt(np.maximum(var, 0.0))[:, None] * self._gp.y_scale[outs]
        return mean, std

    def predict_mean(self, Xs) -> np.ndarray:
        """Zeros, shape (m, L)."""
        return self.predict(Xs)
