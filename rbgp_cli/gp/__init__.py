"""Exact GP regression: NLML and gradient, L-BFGS-B with restarts, PD safeguards, prediction."""

from rbgp_cli.gp.exact import GaussianProcess, OutputFit, fit_gp, nlml_and_gradient

__all__ = ["GaussianProcess", "OutputFit", "fit_gp", "nlml_and_gradient"]
