"""The record of one fitted output (or of all outputs, in shared mode): :class:`OutputFit`, what the
exact and the sparse GP store per hyperparameter set and what model files keep (``to_dict``)."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["OutputFit"]


@dataclass
class OutputFit:
    """What the fit of one output (or of all outputs, in shared mode) found and how.

    values : final hyperparameters {name: value} (noise_std included)
    nlml : negative log marginal likelihood at ``values`` (summed over outputs in shared mode, on the
        standardised outputs)
    jitter : diagonal jitter added to K + σn²I to pass Cholesky / the conditioning check (0 if none)
    rcond : reciprocal condition number of K + (σn² + jitter) I
    positive_definite : K + σn²I (without jitter) passed Cholesky and the conditioning check
    n_evaluations, n_infeasible : NLML evaluations on all n points, and how many of them met a
        non-PD matrix (evaluations on the exploration subsample are counted in ``subsample``)
    starts : per start {"start": {...}, "nlml": final, "status": message, "evaluations": k}
    at_bounds : names of free hyperparameters that ended at a bound
    guarded : the first optimum missed the noise margin (λ_min(K + σn²I) < NOISE_MARGIN σn², possible
        only with an indefinite kernel) and the output was refit with the margin enforced
    subsample : None, or {"size", "evaluations", "infeasible"} when the starts explored a random
        subsample first (n > 2·SUBSAMPLE_SIZE; see :func:`fit_gp`)
    calibration : None, or how σn² was scaled for the posterior by leaving demonstrations out
        (:func:`rbgp_cli.gp.calibration.demonstration_noise_factors`): then ``values[noise_std]`` is the
        posterior's √c σn and ``calibration["noise_std_fitted"]`` the σn at which ``nlml`` was found
    """

    values: dict
    nlml: float
    jitter: float = 0.0
    rcond: float = float("nan")
    positive_definite: bool = True
    n_evaluations: int = 0
    n_infeasible: int = 0
    starts: list = field(default_factory=list)
    at_bounds: list = field(default_factory=list)
    free: list = field(default_factory=list)
    seconds: float = 0.0
    guarded: bool = False
    subsample: dict | None = None
    calibration: dict | None = None

    def to_dict(self) -> dict:
        return {
            "values": {k: float(v) for k, v in self.values.items()},
            "nlml": float(self.nlml),
            "jitter": float(self.jitter),
            "rcond": float(self.rcond),
            "positive_definite": bool(self.positive_definite),
            "n_evaluations": int(self.n_evaluations),
            "n_infeasible": int(self.n_infeasible),
            "starts": self.starts,
            "at_bounds": list(self.at_bounds),
            "free": list(self.free),
            "seconds": float(self.seconds),
            "guarded": bool(self.guarded),
            "subsample": self.subsample,
            "calibration": self.calibration,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "OutputFit":
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})

