"""The training options, declared once: ``rbgp train``, ``rbgp crossval`` (which trains on every fold
with exactly these options) and their help share these definitions and defaults.

The defaults come from :data:`rbgp_cli.dynamics.defaults.DEFAULTS` (chosen by cross-validation; the
README's table says how). Only the standard library and typer are imported here.
"""

from __future__ import annotations

import inspect
from typing import Annotated, Optional

import typer

from rbgp_cli.dynamics.defaults import DEFAULTS

__all__ = [
    "ModelPanel", "RhoOpt", "RestartsOpt", "ExploreOpt", "SeedOpt", "NoiseOpt", "ShareOpt", "SubsampleOpt",
    "MaxPointsOpt", "TrainRateOpt", "SmoothWindowOpt", "SmoothDegreeOpt", "TimeInputOpt", "PriorOpt",
    "PriorGainOpt", "StartCondOpt", "NoiseScaleOpt", "ResidualGainOpt", "InducingOpt", "train_kwargs", "train_option_names", "GRID_LISTS", "grid_variants",
]

ModelPanel = "Model"
_VEL = "Training velocities"

RhoOpt = Annotated[str, typer.Option("--rho-rot", help="Rotation weight ρ1 of eq. 19 in (0, 1), or 'learn'.", rich_help_panel=ModelPanel)]
RestartsOpt = Annotated[int, typer.Option("--restarts", min=1, help="Optimiser starts per output (the data-driven one plus random ones).", rich_help_panel=ModelPanel)]
ExploreOpt = Annotated[int, typer.Option("--explore-size", min=0, help="With more than twice this many training points the starts explore a random subset of this size first and only new basins are refined on all points; 0 runs every start on all points.", rich_help_panel=ModelPanel)]
SeedOpt = Annotated[int, typer.Option("--seed", min=0, help="Seed for subsampling and random starts (and crossval's folds).", rich_help_panel=ModelPanel)]
NoiseOpt = Annotated[str, typer.Option("--noise", help="'learn', or a fixed noise standard deviation (the paper fixes 1).", rich_help_panel=ModelPanel)]
ShareOpt = Annotated[bool, typer.Option("--share-hyperparameters", help="One set of hyperparameters for all outputs (faster).", rich_help_panel=ModelPanel)]
SubsampleOpt = Annotated[float, typer.Option("--subsample", help="Random fraction of the training pairs to use (the paper: 0.1).", rich_help_panel=ModelPanel)]
MaxPointsOpt = Annotated[int, typer.Option("--max-points", min=2, help="At most this many training points for the exact GP (a sparse GP uses all of them; see --inducing).", rich_help_panel=ModelPanel)]
InducingOpt = Annotated[Optional[int], typer.Option("--inducing", min=0, help="A sparse GP (Titsias 2009) with this many inducing poses, on all training points; 0 forces the exact GP (on at most --max-points). Default: the exact GP, unless more than 3000 and more than --max-points points remain: then 256 inducing poses, kept only where it predicts held-out demonstrations no worse than the exact GP on --max-points of them.", rich_help_panel=ModelPanel)]
HyperPointsOpt = Annotated[Optional[int], typer.Option("--hyper-points", min=0, help="The marginal likelihood of this many random training points chooses the hyperparameters (default: 400 for the exact GP, 1000 for the sparse GP, whose hyperparameters are the exact GP's fit on them; 0 = all of them, slower); the posterior always uses every point.", rich_help_panel=ModelPanel)]
CalibrateOpt = Annotated[bool, typer.Option("--calibrate-noise/--no-calibrate-noise", help="After the fit, scale the posterior's noise variance by the factor that predicts held-out demonstrations best (each demonstration left out in turn, on a random 1000 points): the mean rollout then follows the shared motion rather than one training demonstration's own deviations, and the sampled rollouts (--samples) carry the variation between demonstrations. Lowers held-out trajectory errors and makes the bands honest, but the mean rollouts vary less from start to start, which raises their own crossval score; needs two demonstrations (skipped otherwise).", rich_help_panel=ModelPanel)]
TimeInputOpt = Annotated[str, typer.Option("--time-input", help="What the GP sees besides the pose: none (the paper), seconds (since the demonstration's start) or phase (normalised time; outputs per unit phase, so a rollout of any duration traverses the motion once).", rich_help_panel=ModelPanel)]
PriorOpt = Annotated[str, typer.Option("--prior", help="The GP's prior mean: none (zero, the paper), goal (a pull toward the demonstrations' mean final pose) or path (the demonstrations' mean path over phase: its velocity plus a pull toward it; needs --time-input phase). The GP models the residual.", rich_help_panel=ModelPanel)]
PriorGainOpt = Annotated[float, typer.Option("--prior-gain", min=0.0, help="How strongly the prior pulls toward its pose: per unit phase (per second with --time-input seconds or none).", rich_help_panel=ModelPanel)]
StartCondOpt = Annotated[bool, typer.Option("--start-conditioning/--no-start-conditioning", help="With --prior path: pull each motion toward the mean path displaced by the deviation the demonstrations keep from a start like its own (its conditional mean given the start: a ridge map over all six coordinates, its strength by cross-validation), not toward the mean path itself; chosen by crossval.", rich_help_panel=ModelPanel)]
PullProfileOpt = Annotated[bool, typer.Option("--pull-profile/--no-pull-profile", help="With --start-conditioning: the pull's gain per phase and coordinate follows how fast the demonstrations converge on their start-conditioned paths (rising up to 20 per unit phase where they close in on a common pose, e.g. the end of a reach; --prior-gain elsewhere), so a rollout converges as they do; --no-pull-profile: --prior-gain throughout. Chosen by crossval.", rich_help_panel=ModelPanel)]
NoiseScaleOpt = Annotated[float, typer.Option("--noise-scale", min=1.0, help="After the fit (and --calibrate-noise), multiply the posterior's noise variance by this factor (1: not): the mean rollout then leans further on the prior's motion (--prior path: the start-conditioned mean path) and less on the training demonstrations' own deviations; chosen by crossval.", rich_help_panel=ModelPanel)]
ResidualGainOpt = Annotated[str, typer.Option("--residual-gain", metavar="auto|G", help="The gain g on the GP's residual mean: velocity = prior mean + g × the GP's residual. auto (the default) chooses g from 0, 0.25, 0.5, 1 by rolling out each demonstration with the GP that has not seen it (the smaller gain unless a larger one is better by more than one standard error); a number fixes it (1: the full GP, 0: the path distribution alone). rbgp info shows the gain and the left-out errors.", rich_help_panel=ModelPanel)]
TrainRateOpt = Annotated[float, typer.Option("--train-rate", min=0.0, help="Resample each demonstration to this rate (Hz) before estimating velocities; the rollout step follows it. 0 keeps the recorded samples.", rich_help_panel=_VEL)]
SmoothWindowOpt = Annotated[float, typer.Option("--smooth-window", min=0.0, help="Estimate velocities by a local polynomial fit over this many seconds around each sample (Savitzky–Golay type, in the rotation's tangent space); 0: forward differences.", rich_help_panel=_VEL)]
SmoothDegreeOpt = Annotated[int, typer.Option("--smooth-degree", min=1, max=4, help="Degree of the local polynomial fit.", rich_help_panel=_VEL)]


def train_kwargs(*, rho_rot: str, restarts: int, explore_size: int, seed: int, noise: str, share_hyperparameters: bool,
                 subsample: float, max_points: int, train_rate: float, smooth_window: float, smooth_degree: int,
                 time_input: str, prior: str, prior_gain: float, inducing: int | None = None,
                 hyper_points: int | None = None, calibrate_noise: bool = DEFAULTS["calibrate"],
                 start_conditioning: bool = DEFAULTS["start_conditioning"],
                 noise_scale: float = DEFAULTS["noise_scale"], pull_profile: bool = DEFAULTS["pull_profile"],
                 residual_gain: str = DEFAULTS["residual_gain"]) -> dict:
    """Check the option values and build the keyword arguments of
    :func:`rbgp_cli.dynamics.model.train_model` (without representation and kernel): the library's
    :func:`rbgp_cli.api.train_options`, whose errors name the parameters (the command shows the flags)."""
    from rbgp_cli.api import train_options

    return train_options(rho_rot=rho_rot, restarts=restarts, explore_size=explore_size, seed=seed, noise=noise,
                         share_hyperparameters=share_hyperparameters, subsample=subsample, max_points=max_points,
                         train_rate=train_rate, smooth_window=smooth_window, smooth_degree=smooth_degree,
                         time_input=time_input, prior=prior, prior_gain=prior_gain, inducing=inducing,
                         hyper_points=hyper_points, calibrate_noise=calibrate_noise,
                         start_conditioning=start_conditioning, noise_scale=noise_scale, pull_profile=pull_profile,
                         residual_gain=residual_gain)


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


#: What ``--grid`` takes besides the options of :func:`train_kwargs`: the two that ``rbgp crossval``
#: repeats itself (``--grid kernel=se,dot`` is ``--kernel se --kernel dot``).
GRID_LISTS = ("representation", "kernel")


def train_option_names() -> tuple[str, ...]:
    """The declared training options: the parameters of :func:`train_kwargs` (Python names; the option
    is ``--`` + the name with ``-`` for ``_``). A new option added there is a --grid option too."""
    return tuple(inspect.signature(train_kwargs).parameters)


def grid_variants(ctx, specs) -> tuple[list[tuple[str, dict, dict]], dict]:
    """Parse ``--grid NAME=V1,V2,...`` (repeatable) for ``rbgp crossval``: the Cartesian product of the
    grids of training options.

    ``ctx`` is the running command's context: each value is converted and checked by the command's own
    option (the same type, range and message as the option typed alone), then every combination by
    :func:`train_kwargs` with the other options as given. ``default`` stands for the option's default.
    An option may not be given both alone and in a grid, nor in two grids.

    Returns (variants, lists): ``variants`` one ``(label, options, train_kwargs)`` per combination,
    ``label`` e.g. ``"prior-gain=3 inducing=0"`` (empty without grids), ``options`` {CLI name: value};
    ``lists`` {"representation": [...], "kernel": [...]} from grids of those two.
    """
    from itertools import product

    from rbgp_cli.errors import InputError

    names = train_option_names()
    params = {p.name: p for p in ctx.command.params}
    base = {n: ctx.params[n] for n in names}
    valid = ", ".join([n.replace("_", "-") for n in names] + list(GRID_LISTS))
    grids: dict = {}
    lists: dict = {}
    for spec in specs or []:
        name, sep, values = str(spec).partition("=")
        key = name.strip().lstrip("-").replace("-", "_")
        flag = key.replace("_", "-")
        texts = [v.strip() for v in values.split(",")]
        if not sep or not key or not all(texts):
            raise InputError(f"--grid {spec!r} is not NAME=VALUE,VALUE,...", hint="e.g. --grid prior-gain=3,5,10")
        if key in GRID_LISTS:
            lists.setdefault(key, []).extend(texts)
            continue
        if key not in names:
            from rbgp_cli.errors import closest

            near = closest(flag, valid.split(", "))
            raise InputError(f"--grid: {name.strip()!r} is not a training option",
                             hint=(f"did you mean {near}? " if near else "") + f"expected one of {valid}")
        if key in grids:
            raise InputError(f"--grid {flag} is given twice", hint="list all its values in one --grid")
        source = ctx.get_parameter_source(key)
        if source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP"):
            raise InputError(f"give --{flag} or --grid {flag}=..., not both")
        values_of: dict = {}
        for text in texts:
            if text == "default":
                value = base[key]
            else:
                try:
                    value = params[key].process_value(ctx, text)
                except Exception as exc:  # the option's own check (click's BadParameter)
                    msg = exc.format_message() if hasattr(exc, "format_message") else str(exc)
                    raise InputError(f"--grid {flag}={text}: {msg}") from None
            values_of.setdefault(repr(value), (text, value))  # 3 and 3.0 are one value
        grids[key] = list(values_of.values())
    variants = []
    for combo in product(*grids.values()):
        label = " ".join(f"{k.replace('_', '-')}={t}" for k, (t, _) in zip(grids, combo))
        chosen = {k: v for k, (_, v) in zip(grids, combo)}
        try:
            kwargs = train_kwargs(**{**base, **chosen})
        except InputError as exc:
            raise InputError(exc.message + (f" (in the --grid combination {label})" if label else ""), hint=exc.hint,
                             param=exc.param) from None
        variants.append((label, {k.replace("_", "-"): v for k, v in chosen.items()}, kwargs))
    return variants, lists
