"""The training options, declared once: ``rbgp train``, ``rbgp crossval`` (which trains on every fold
with exactly these options) and their help share these definitions and defaults.

The defaults come from :data:`rbgp_cli.dynamics.defaults.DEFAULTS` (chosen by cross-validation; the
README's table says how). Only the standard library and typer are imported here.
"""

from __future__ import annotations

from typing import Annotated, Optional

import typer

__all__ = [
    "ModelPanel", "RhoOpt", "RestartsOpt", "ExploreOpt", "SeedOpt", "NoiseOpt", "ShareOpt", "SubsampleOpt",
    "MaxPointsOpt", "TrainRateOpt", "SmoothWindowOpt", "SmoothDegreeOpt", "TimeInputOpt", "PriorOpt",
    "PriorGainOpt", "InducingOpt", "train_kwargs",
]

ModelPanel = "Model"
_VEL = "Training velocities"

RhoOpt = Annotated[str, typer.Option("--rho-rot", help="Rotation weight ρ1 of eq. 19 in (0, 1), or 'learn'.", rich_help_panel=ModelPanel)]
RestartsOpt = Annotated[int, typer.Option("--restarts", min=1, help="Optimiser starts per output (the data-driven one plus random ones).", rich_help_panel=ModelPanel)]
ExploreOpt = Annotated[int, typer.Option("--explore-size", min=0, help="With more than twice this many training points the starts explore a random subset of this size first and only new basins are refined on all points; 0 runs every start on all points.", rich_help_panel=ModelPanel)]
SeedOpt = Annotated[int, typer.Option("--seed", help="Seed for subsampling and random starts (and crossval's folds).", rich_help_panel=ModelPanel)]
NoiseOpt = Annotated[str, typer.Option("--noise", help="'learn', or a fixed noise standard deviation (the paper fixes 1).", rich_help_panel=ModelPanel)]
ShareOpt = Annotated[bool, typer.Option("--share-hyperparameters", help="One set of hyperparameters for all outputs (faster).", rich_help_panel=ModelPanel)]
SubsampleOpt = Annotated[float, typer.Option("--subsample", help="Random fraction of the training pairs to use (the paper: 0.1).", rich_help_panel=ModelPanel)]
MaxPointsOpt = Annotated[int, typer.Option("--max-points", min=2, help="At most this many training points for the exact GP (a sparse GP uses all of them; see --inducing).", rich_help_panel=ModelPanel)]
InducingOpt = Annotated[Optional[int], typer.Option("--inducing", min=0, help="A sparse GP (Titsias 2009) with this many inducing poses, on all training points; 0 forces the exact GP (on at most --max-points). Default: the exact GP, unless more than 3000 and more than --max-points points remain: then 512 inducing poses.", rich_help_panel=ModelPanel)]
HyperPointsOpt = Annotated[Optional[int], typer.Option("--hyper-points", min=0, help="Sparse GP only: the bound that chooses the hyperparameters covers this many random training points (default 4 × the inducing poses, at least 2000; 0 = all of them, slower); the posterior always uses every point.", rich_help_panel=ModelPanel)]
CalibrateOpt = Annotated[bool, typer.Option("--calibrate-noise", help="After the fit, scale the posterior's noise variance by the factor that predicts held-out demonstrations best (cross-validation by demonstration on a random 1000 points): the posterior then follows the shared motion rather than each training demonstration's own deviations. Lowers held-out velocity and trajectory errors, most at high rates (--train-rate 0), but rollouts vary less, which worsens the crossval score; needs two demonstrations.", rich_help_panel=ModelPanel)]
TimeInputOpt = Annotated[str, typer.Option("--time-input", help="What the GP sees besides the pose: none (the paper), seconds (since the demonstration's start) or phase (normalised time; outputs per unit phase, so a rollout of any duration traverses the motion once).", rich_help_panel=ModelPanel)]
PriorOpt = Annotated[str, typer.Option("--prior", help="The GP's prior mean: none (zero, the paper), goal (a pull toward the demonstrations' mean final pose) or path (the demonstrations' mean path over phase: its velocity plus a pull toward it; needs --time-input phase). The GP models the residual.", rich_help_panel=ModelPanel)]
PriorGainOpt = Annotated[float, typer.Option("--prior-gain", min=0.0, help="How strongly the prior pulls toward its pose: per unit phase (per second with --time-input seconds or none).", rich_help_panel=ModelPanel)]
TrainRateOpt = Annotated[float, typer.Option("--train-rate", min=0.0, help="Resample each demonstration to this rate (Hz) before estimating velocities; the rollout step follows it. 0 keeps the recorded samples.", rich_help_panel=_VEL)]
SmoothWindowOpt = Annotated[float, typer.Option("--smooth-window", min=0.0, help="Estimate velocities by a local polynomial fit over this many seconds around each sample (Savitzky–Golay type, in the rotation's tangent space); 0: forward differences.", rich_help_panel=_VEL)]
SmoothDegreeOpt = Annotated[int, typer.Option("--smooth-degree", min=1, max=4, help="Degree of the local polynomial fit.", rich_help_panel=_VEL)]


def _number(text: str, flag: str) -> float:
    from rbgp_cli.errors import InputError

    try:
        v = float(text)
    except ValueError:
        raise InputError(f"{flag} must be a number, got {text!r}") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise InputError(f"{flag} must be finite, got {text!r}")
    return v


def _choice(value: str, flag: str, choices: tuple) -> str | None:
    from rbgp_cli.errors import InputError

    if value not in choices:
        raise InputError(f"{flag} must be one of {', '.join(choices)}, got {value!r}")
    return None if value == "none" else value


def train_kwargs(*, rho_rot: str, restarts: int, explore_size: int, seed: int, noise: str, share_hyperparameters: bool,
                 subsample: float, max_points: int, train_rate: float, smooth_window: float, smooth_degree: int,
                 time_input: str, prior: str, prior_gain: float, inducing: int | None = None,
                 hyper_points: int | None = None, calibrate_noise: bool = False) -> dict:
    """Check the option values and build the keyword arguments of
    :func:`rbgp_cli.dynamics.model.train_model` (without representation and kernel)."""
    from rbgp_cli.dynamics.velocities import VelocityOptions
    from rbgp_cli.errors import InputError

    rho = rho_rot if rho_rot == "learn" else _number(rho_rot, "--rho-rot")
    noise_v = None if noise == "learn" else _number(noise, "--noise")
    if noise_v is not None and not noise_v > 0:
        raise InputError(f"--noise must be 'learn' or a positive number, got {noise}")
    time_in = _choice(time_input, "--time-input", ("none", "seconds", "phase"))
    prior_v = _choice(prior, "--prior", ("none", "goal", "path"))
    if prior_v == "path" and time_in != "phase":
        raise InputError("--prior path follows the phase of the motion", hint="add --time-input phase, or use --prior goal or none")
    return {
        "rho_rot": rho, "restarts": restarts, "explore_size": explore_size, "seed": seed, "noise": noise_v,
        "shared": share_hyperparameters, "subsample": subsample, "max_points": max_points,
        "velocity": VelocityOptions(rate=train_rate or None, window=smooth_window, degree=smooth_degree),
        "time_input": time_in, "prior": prior_v, "prior_gain": prior_gain, "inducing": inducing,
        **({"hyper_points": hyper_points} if hyper_points is not None else {}),
        **({"calibrate": True} if calibrate_noise else {}),
    }


def defaults() -> dict:
    """The CLI spellings of :data:`rbgp_cli.dynamics.defaults.DEFAULTS` (``none`` for None, 0 for the recorded rate)."""
    from rbgp_cli.dynamics.defaults import DEFAULTS

    d = dict(DEFAULTS)
    return {**d, "train_rate": d["train_rate"] or 0.0, "time_input": d["time_input"] or "none",
            "prior": d["prior"] or "none", "rho_rot": str(d["rho_rot"])}


def kernel_help() -> str:
    """The --kernel help with the defaults of :data:`rbgp_cli.dynamics.defaults.DEFAULT_KERNELS`."""
    from rbgp_cli.dynamics.defaults import DEFAULT_KERNELS

    by = ", ".join(f"{k} for {r}" for r, k in DEFAULT_KERNELS.items())
    return ("se-chordal (the squared exponential on the chordal rotation distance: positive definite for every "
            "λ), se (the paper's eq. 24 on the representation's own rotation distance: the geodesic one for "
            "axis-angle, not positive definite for every length-scale; Euclidean for euler) or dot (eq. 22). "
            f"Default: {by}.")
