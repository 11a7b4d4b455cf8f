"""Gaussian-process regression: the exact GP (:mod:`~rbgp_cli.gp.exact`), its likelihood
(:mod:`~rbgp_cli.gp.likelihood`) and optimiser (:mod:`~rbgp_cli.gp.optimise`, shared with the sparse GP
of :mod:`~rbgp_cli.gp.sparse`), the fit record (:mod:`~rbgp_cli.gp.results`) and the posterior protocol
both GPs satisfy (:mod:`~rbgp_cli.gp.posterior`)."""

from rbgp_cli.gp.exact import GaussianProcess, fit_gp
from rbgp_cli.gp.likelihood import nlml_and_gradient
from rbgp_cli.gp.results import OutputFit

__all__ = ["GaussianProcess", "OutputFit", "fit_gp", "nlml_and_gradient"]
