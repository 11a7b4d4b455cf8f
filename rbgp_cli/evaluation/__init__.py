"""Evaluation: resampling, per-step Gaussians and the Bhattacharyya distance to the demonstrations (docs/method.md §9).

* :mod:`~rbgp_cli.evaluation.resample`: trajectories on normalised time s ∈ [0, 1] (slerp / linear),
  the chordal mean rotation per step, features ``(log(R̄_tᵀ R), p)`` in the tangent space at it.
* :mod:`~rbgp_cli.evaluation.bhattacharyya`: D_B of Gaussians (full or diagonal covariance) and
  :func:`evaluate`, the score of generated trajectories against demonstrations (paper sec. 4.3), and
  :func:`check_sample_sizes`, how many trajectories per set the fitted covariance needs.
"""

from rbgp_cli.evaluation.bhattacharyya import (
    MIN_TRAJECTORIES,
    EvaluationResult,
    SampleSizeCheck,
    bhattacharyya_diag,
    bhattacharyya_gaussian,
    check_sample_sizes,
    evaluate,
)
from rbgp_cli.evaluation.resample import mean_rotation, resample, resample_all, tangent_features

__all__ = [
    "resample",
    "resample_all",
    "mean_rotation",
    "tangent_features",
    "bhattacharyya_gaussian",
    "bhattacharyya_diag",
    "EvaluationResult",
    "evaluate",
    "check_sample_sizes",
    "SampleSizeCheck",
    "MIN_TRAJECTORIES",
]
