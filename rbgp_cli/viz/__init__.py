"""Visualisation at the edge of the library: Rerun recordings and matplotlib figures.

* :mod:`~rbgp_cli.viz.recording`: ``.rrd`` files of training data (:func:`record_training`),
  rollouts (:func:`record_rollout`) and evaluations (:func:`record_evaluation`), each with a
  default blueprint (``rbgp ... --rerun FILE``).
* :mod:`~rbgp_cli.viz.plots`: :func:`plot_evaluation`, a PNG like the paper's Fig. 4/5
  (``rbgp evaluate --plot FILE``).

rerun and matplotlib are imported inside these functions only, so importing this package (or
anything else in rbgp) never loads them. Every file is written atomically.
"""

from rbgp_cli.viz.plots import plot_evaluation
from rbgp_cli.viz.recording import record_evaluation, record_rollout, record_training

__all__ = ["record_training", "record_rollout", "record_evaluation", "plot_evaluation"]
