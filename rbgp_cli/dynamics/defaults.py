"""The default training options of ``rbgp train``, ``rbgp crossval`` and ``rbgp demo``, in one place.

They were chosen by held-out evaluation (``rbgp crossval``) on real recordings and the bundled sample
data; the README's table "How the defaults were chosen" gives the numbers. Imports nothing, so the
command line can read them without loading numpy.
"""

#: Keyword arguments of :func:`rbgp_cli.dynamics.model.train_model` (velocity estimation spelled out).
DEFAULTS = {
    "representation": "axis-angle",
    "kernel": None,  # the representation's own: DEFAULT_KERNELS
    "rho_rot": 0.7,
    "restarts": 3,
    "explore_size": 400,
    "subsample": 1.0,
    "max_points": 2000,
    "train_rate": 10.0,  # Hz; None keeps the recorded samples
    "smooth_window": 0.0,  # seconds; 0 = forward differences
    "smooth_degree": 2,
    "time_input": "phase",
    "prior": "path",
    # the pull toward the (start-conditioned) mean path, per unit phase: weak, because the reference
    # path already starts where the rollout starts; 10 kept rollouts on it as well but turned the
    # velocity field off the path into the pull (held-out velocities worse than predicting zero on
    # the handovers; docs/defaults.md, "December 2026 (before the secant)")
    "prior_gain": 1.0,
    # the mean path moved by the deviation the demonstrations keep from a start like the rollout's
    # (a ridge map over all six coordinates, its strength by cross-validation; docs/method.md §7)
    "start_conditioning": True,
    # with start conditioning: the pull's gain rises (up to 20 per unit phase) where the demonstrations
    # converge on their start-conditioned paths, so rollouts converge as people do (the end of a hand
    # raise); --prior-gain elsewhere (docs/method.md §7, "The pull's profile"; docs/defaults.md)
    "pull_profile": True,
    # σn² of the posterior scaled by held-out demonstrations (gp/calibration.py): the mean rollout then
    # follows the shared motion and the sampled rollouts carry the variation between demonstrations
    "calibrate": True,
    # a further factor on σn² of the posterior, after the calibration (1: none): the GP's residual
    # field trusts the training pairs less and the mean stays nearer the start-conditioned mean path
    # (docs/defaults.md measured 1, 16, 256, 4096; 256 with the weak pull is the default)
    "noise_scale": 256.0,
    # the gain g on the GP's residual mean, ξ = m + g·μ_GP: "auto" chooses it from {0, ¼, ½, 1} by rolling
    # out each demonstration with the GP that has not seen it (dynamics/residual_gain.py; docs/defaults.md,
    # "The GP's residual, chosen by leaving demonstrations out"); a number fixes it (1: the full model)
    "residual_gain": "auto",
}

#: The kernel each representation trains with unless one is named (``kernel=None``).
DEFAULT_KERNELS = {"axis-angle": "se-chordal", "quaternion": "se-chordal", "euler": "se"}

#: The exact GP's hyperparameters come from the NLML of a random subset of this many training points
#: (``hyper_points=None``; 0: all of them), and its posterior uses every point (docs/defaults.md,
#: "training in seconds"). The sparse GP has its own default (rbgp_cli.gp.sparse.HYPER_EXACT_POINTS).
EXACT_HYPER_POINTS = 400
