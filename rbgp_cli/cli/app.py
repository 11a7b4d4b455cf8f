"""The ``rbgp`` command line: parse, call one library function (:mod:`rbgp_cli.workflows`), print.

stdout carries data (CSV or JSON); progress, warnings and errors go to stderr. Exit codes: 0 ok,
1 runtime failure, 2 bad usage or bad input. Heavy libraries are imported inside the commands.
"""

from __future__ import annotations

import math
import sys
from typing import Annotated, List, Optional

import typer

from rbgp_cli import __version__
from rbgp_cli.cli.args import RbgpGroup, paths_option
from rbgp_cli.cli.train_options import (
    ExploreOpt, MaxPointsOpt, NoiseOpt, NoiseScaleOpt, PriorGainOpt, PriorOpt, PullProfileOpt, ResidualGainOpt, StartCondOpt, RestartsOpt, RhoOpt, SeedOpt, ShareOpt, SmoothDegreeOpt,
    CalibrateOpt, HyperPointsOpt, InducingOpt, SmoothWindowOpt, SubsampleOpt, TimeInputOpt, TrainRateOpt, defaults, kernel_help, train_kwargs,
)
from rbgp_cli.cli.common import (
    ReadArgs, as_flags, command, emit_json, flag_words, check_files, check_outputs, is_quiet, need_flags, progress, set_json, set_quiet,
    with_read_options, write_text_output,
)

app = typer.Typer(
    name="rbgp",
    help="Learn rigid-body motion from motion-capture demonstrations with the rigid-body Gaussian "
    "process (Lang & Hirche), generate new motions, and score them against the demonstrations.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    cls=RbgpGroup,  # several paths after one flag, as a shell expands a glob (rbgp_cli/cli/args.py)
)

_TRAIN = "Model"
_OUT = "Output"
_D = defaults()  # the training defaults (rbgp_cli/dynamics/defaults.py), spelled as the options take them


def _version(value: bool):
    if value:
        print(f"rbgp {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option("--version", "-V", callback=_version, is_eager=True, help="Print the version.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress messages, bars or summaries on stderr (warnings and errors still); also accepted after the command.")] = False,
    json_out: Annotated[bool, typer.Option("--json", help="The command's --json (machine-readable output on stdout), for the commands that have it.")] = False,
):
    set_quiet(quiet)
    set_json(json_out)


# ---------------------------------------------------------------------------------------------- train
@app.command()
@command
@with_read_options
def train(
    demos: Annotated[List[str], typer.Argument(help="Demonstration files or directories ('-' reads a CSV from stdin).")],
    output: Annotated[str, typer.Option("--output", "-o", help="Model file to write (written atomically).", rich_help_panel=_OUT)],
    representation: Annotated[str, typer.Option(help="axis-angle (the paper's rigid-body GP), euler or quaternion.", rich_help_panel=_TRAIN)] = _D["representation"],
    kernel: Annotated[Optional[str], typer.Option(help=kernel_help(), rich_help_panel=_TRAIN)] = None,
    rho_rot: RhoOpt = _D["rho_rot"], restarts: RestartsOpt = _D["restarts"], explore_size: ExploreOpt = _D["explore_size"],
    seed: SeedOpt = 0, noise: NoiseOpt = "learn", share_hyperparameters: ShareOpt = False,
    subsample: SubsampleOpt = _D["subsample"], max_points: MaxPointsOpt = _D["max_points"],
    time_input: TimeInputOpt = _D["time_input"], prior: PriorOpt = _D["prior"], prior_gain: PriorGainOpt = _D["prior_gain"],
    train_rate: TrainRateOpt = _D["train_rate"], smooth_window: SmoothWindowOpt = _D["smooth_window"],
    smooth_degree: SmoothDegreeOpt = _D["smooth_degree"], inducing: InducingOpt = None,
    hyper_points: HyperPointsOpt = None, calibrate_noise: CalibrateOpt = _D["calibrate"],
    start_conditioning: StartCondOpt = _D["start_conditioning"], noise_scale: NoiseScaleOpt = _D["noise_scale"],
    pull_profile: PullProfileOpt = _D["pull_profile"], residual_gain: ResidualGainOpt = _D["residual_gain"],
    jobs: Annotated[int, typer.Option(min=0, help="Worker processes for the per-output fits (BLAS single-threaded in each; the model does not depend on it); 0 = one per output, fewer if memory is short, 1 on a single core.", rich_help_panel=_TRAIN)] = 0,
    json_out: Annotated[bool, typer.Option("--json", help="Print the summary as JSON on stdout.", rich_help_panel=_OUT)] = False,
    rerun: Annotated[Optional[str], typer.Option("--rerun", help="Also write a Rerun recording (.rrd) of the demonstrations and training points.", rich_help_panel=_OUT)] = None,
    up: Annotated[str, typer.Option(help="World up axis for the recording: z or y.", rich_help_panel=_OUT)] = "z",
    read: ReadArgs = None,
):
    """Train a motion model on demonstrations.

    Example: rbgp train sample_data/csv -o shoe.rbgp
    """
    from rbgp_cli import workflows
    from rbgp_cli.errors import InputError

    opts, max_gap = read.options, read.max_gap
    kwargs = train_kwargs(rho_rot=rho_rot, restarts=restarts, explore_size=explore_size, seed=seed, noise=noise,
                          share_hyperparameters=share_hyperparameters, subsample=subsample, max_points=max_points,
                          train_rate=train_rate, smooth_window=smooth_window, smooth_degree=smooth_degree,
                          time_input=time_input, prior=prior, prior_gain=prior_gain, inducing=inducing,
                          hyper_points=hyper_points, calibrate_noise=calibrate_noise,
                          start_conditioning=start_conditioning, noise_scale=noise_scale,
                          pull_profile=pull_profile, residual_gain=residual_gain)
    if up not in ("z", "y"):
        raise InputError(f"--up must be z or y, got {up!r}")
    if output == "-":  # '-' is stdout elsewhere; the model is a binary zip that every command reads by name
        raise InputError("-o - would write the model to stdout, but a model is a file (a binary zip read back by name)",
                         hint="give -o NAME.rbgp")
    check_files({"--rerun": rerun})
    check_outputs(output, rerun)
    model, header, trajs = workflows.train_from_files(
        demos, output, options=opts, max_gap=max_gap, progress=progress,
        representation=representation, kernel=kernel, jobs=jobs or None, **kwargs,
    )
    if rerun:
        from rbgp_cli.viz.recording import record_training

        record_training(rerun, trajs, model, up=up)
        progress(f"wrote {rerun}")
    summary = dict(model.summary)
    summary["model"] = output
    if json_out:
        emit_json(summary)
    elif not is_quiet():  # the summary is information: -q leaves stderr to warnings and errors
        from rbgp_cli.cli.report import format_train_summary

        print(format_train_summary(summary), file=sys.stderr)


# ---------------------------------------------------------------------------------------------- info
@app.command()
@command
def info(
    model: Annotated[str, typer.Argument(help="Model file written by rbgp train.")],
    json_out: Annotated[bool, typer.Option("--json", help="Print the header as JSON.")] = False,
):
    """Show what a model file holds and how it was made (verifies it as every command loading it does:
    checksums of the header and the arrays, every field, the GP rebuilt)."""
    from rbgp_cli.io.model_store import load_model

    m, header = load_model(model)
    header = dict(header)
    header["training_points"] = int(m.gp.X.shape[0])
    if json_out:
        emit_json(header)
    else:
        from rbgp_cli.cli.report import format_model_info

        print(format_model_info(model, header))


# ---------------------------------------------------------------------------------------------- predict
@app.command()
@command
@with_read_options
def predict(
    model: Annotated[str, typer.Argument(help="Model file.")],
    poses: Annotated[str, typer.Argument(help="Poses: a CSV (any pose columns the reader knows; '-' for stdin), or any file rbgp train reads.")],
    output: Annotated[Optional[str], typer.Option("--output", "-o", help="CSV to write (default: stdout).")] = None,
    noisy: Annotated[bool, typer.Option("--noisy", help="Std of a new noisy observation instead of the latent function's.")] = False,
    read: ReadArgs = None,
):
    """Predict the velocity (mean and standard deviation) at each pose of a CSV file.

    A model trained with a time input (--time-input seconds or phase) also needs the time of each pose:
    the file then holds trajectories (a time column; several with a demo column), and each pose's
    time since its trajectory's start (or its phase) is what the model sees. Outputs are per second.
    """
    from rbgp_cli import workflows
    from rbgp_cli.io.model_store import load_model

    check_outputs(output or "-")
    m, _ = load_model(model)
    rows_of: list = []
    t, q, p, mean, std = workflows.predict_file(m, poses, read.options, noisy=noisy, max_gap=read.max_gap,
                                                names=rows_of)  # '-' too
    names = list(m.representation.output_names)
    time_col = ["t"] if t is not None else []
    several = len(set(rows_of)) > 1  # trajectories told apart, as a rollout file names them

    def write(fh):
        fh.write(",".join((["trajectory"] if several else []) + time_col + ["x", "y", "z", "qx", "qy", "qz", "qw"]
                          + [f"mean_{n}" for n in names] + [f"std_{n}" for n in names]) + "\n")
        for i, row in enumerate(zip(p, q, mean, std)):
            # a name quoted as CSV quotes it, as rollout writes names
            lead = (['"' + str(rows_of[i]).replace('"', '""') + '"'] if several else []) + \
                ([repr(float(t[i]))] if t is not None else [])
            fh.write(",".join(lead + [repr(float(v)) for part in row for v in part]) + "\n")

    write_text_output(output, write)


# ---------------------------------------------------------------------------------------------- rollout
@app.command()
@command
@with_read_options
def rollout(
    model: Annotated[str, typer.Argument(help="Model file.")],
    start: Annotated[Optional[List[str]], typer.Option("--start", help='Start pose "rx ry rz x y z" (rotation vector in rad, m); repeatable.')] = None,
    start_quat: Annotated[Optional[List[str]], typer.Option("--start-quat", help='Start pose "qx qy qz qw x y z" (quaternion x, y, z, w, normalised here; m); repeatable.')] = None,
    starts: Annotated[Optional[str], typer.Option("--starts", help="File of start poses, one per row (read with the read options below).")] = None,
    from_demos: Annotated[Optional[List[str]], paths_option("--from-demos", help="Draw starts near these demonstrations' start poses: files or folders, several after one flag (e.g. --from-demos data/*.csv), read with the read options below (--topic for an MCAP with several pose topics).")] = None,
    given: Annotated[Optional[List[str]], paths_option("--given", help="The seen beginnings of motions under way: files, folders or globs (as --from-demos), read with the read options below. Each is continued from its last seen sample to its predicted end (docs/method.md §13): trajectory i (samples i.s0, ...) starts at the last seen time on the file's own clock; --samples draws the duration and the path together; --json reports per file the phase, the predicted end time and end pose with 90 % bands.")] = None,
    count: Annotated[Optional[int], typer.Option(min=1, help="Number of starts drawn near the demonstrations' (or the model's stored) start poses: start i near demonstration i of --from-demos, in the order they are read, cycling (default: one per demonstration of --from-demos, else 1).")] = None,
    start_spread: Annotated[Optional[float], typer.Option("--start-spread", min=0.0, help="Std of the start perturbation in metres (rotation: 0.1 rad per 0.3 m); 0 for the demonstrations' own starts. Default: drawn like the demonstrations' starts, with their mean and covariance (docs/method.md §8).")] = None,
    steps: Annotated[Optional[int], typer.Option(min=1, help="Integration steps (default: the demonstrations' median duration / dt).")] = None,
    duration: Annotated[Optional[float], typer.Option(help="Duration in seconds instead of --steps.")] = None,
    goal: Annotated[Optional[str], typer.Option("--goal", help='Goal pose "qx qy qz qw x y z" (quaternion x, y, z, w; m) where every motion ends: the mean ends there (within about 1 mm / 2 mrad), and in between is what the demonstrations say a motion between start and goal looks like (docs/method.md §12). Default duration: what the demonstrations suggest for this start and goal. A goal far from where the demonstrations end is warned about.')] = None,
    goals: Annotated[Optional[str], typer.Option("--goals", help="File of goal poses, one per start in the order of the starts (for --from-demos the order the demonstrations are read, as the trajectory names 0, 1, ... say), read like --starts.")] = None,
    via: Annotated[Optional[List[str]], typer.Option("--via", help='Via-point "T: qx qy qz qw x y z": the motion passes this pose T seconds after its start; repeatable.')] = None,
    goal_tolerance: Annotated[Optional[str], typer.Option("--goal-tolerance", help='A softer goal and via-points: "ROT_RAD POS_M", one standard deviation of how far from them the motion may end or pass (default: reach them).')] = None,
    each_duration: Annotated[bool, typer.Option("--each-duration", help="With --from-demos: each start lasts as long as the demonstration it was drawn near (other starts: --duration, or the median).")] = False,
    dt: Annotated[Optional[float], typer.Option(help="Integration step in seconds. Default: the demonstrations' recorded sample interval (at most 10 steps per training step; model files without the recorded rate: the training step), so that a curved motion written at the recorded rate is integrated at every sample instead of interpolated between training steps; with --steps, the training step. A different step changes the motion, while --output-rate only writes more points of the same one.")] = None,
    output_rate: Annotated[Optional[float], typer.Option("--output-rate", min=0.0, help="Rate (Hz) of the written trajectories. Default: the demonstrations' recorded rate (their median sample rate, stored in the model; model files from before rbgp stored it: the integration grid). The motion is integrated on --dt either way and resampled, slerp for the rotation and linear for the position and the stds, so the poses at the integration steps do not depend on the rate. 0 writes the integration grid. (--rate is the sample rate of input files without a time column, as in every command.)")] = None,
    samples: Annotated[int, typer.Option(min=0, help="Sampled rollouts per start: the mean rollout displaced by a smooth draw of how the demonstrations differ from one another (the variation model, docs/method.md §11), zero at the start, one alternative way of doing the task each. A model trained on fewer than 3 demonstrations has no variation model; its samples draw each step's velocity from the GP's predictive distribution instead.")] = 0,
    seed: Annotated[int, typer.Option(min=0, help="Seed for start perturbations and Monte Carlo draws.")] = 0,
    no_std: Annotated[bool, typer.Option("--no-std", help="Skip the predictive standard deviations (faster).")] = False,
    off_data: Annotated[str, typer.Option("--off-data", help="What a rollout does once it leaves the demonstrations' envelope (the positions they reach near the same phase of the motion, widened by 25 % of their largest extent, at least 5 cm): keep (go on), stop (end the trajectory at its first sample outside) or prior (while outside, follow the prior mean alone: the mean-path prior's pull back toward the demonstrations). Every mode warns and marks those samples (CSV column left_data = 1; --json: left_data).")] = "keep",
    output: Annotated[Optional[str], typer.Option("--output", "-o", help="File to write ('-' or omitted: stdout): a CSV, or an MCAP when it ends in .mcap, or a rosbag2 folder (the MCAP and its metadata.yaml) when it ends in '/'.")] = None,
    output_format: Annotated[Optional[str], typer.Option("--output-format", help="csv or mcap, whatever -o's name (default: from the name as -o says).")] = None,
    mcap_encoding: Annotated[str, typer.Option("--mcap-encoding", help="MCAP messages: ros2 (geometry_msgs/msg/PoseStamped in CDR, what ros2 bag and RViz read; with --samples 2 or more also a PoseWithCovarianceStamped band per start, the samples' spread about the mean rollout) or foxglove (foxglove.PoseInFrame in protobuf; no band). One topic per trajectory: /rbgp/rollout_0, its samples /rbgp/rollout_0/sample_0, ...")] = "ros2",
    frame_id: Annotated[Optional[str], typer.Option("--frame-id", help="Frame id of the MCAP messages (default: the demonstrations' frame when the model stored one, else world).")] = None,
    start_time: Annotated[float, typer.Option("--start-time", help="Time of the MCAP's first message in seconds since the epoch (e.g. a recording's start, to play both side by side): every message's log time and stamp is this plus t.")] = 0.0,
    json_out: Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout (requires -o FILE).")] = False,
    rerun: Annotated[Optional[str], typer.Option("--rerun", help="Also write a Rerun recording (.rrd).")] = None,
    plot: Annotated[Optional[str], typer.Option("--plot", help="Also write a figure (PNG, or PDF or SVG by the file's suffix): each dimension over time, the mean rollouts as lines, with --samples the next motion's 90 % band around each, goals as crosses at the end, via-points as diamonds, samples outside the demonstrations circled (rotation relative to the first rollout's start).")] = None,
    up: Annotated[str, typer.Option(help="World up axis for the recording: z or y.")] = "z",
    read: ReadArgs = None,
):
    """Generate new motions from start poses by single-step mean prediction.

    Each step takes the model's mean velocity at the current pose and integrates it over one time
    step (with the exponential map for axis-angle; by addition for the euler and quaternion baselines).
    With --goal (or --goals) and --via the motions end at the goal and pass the via-points, bent as
    the demonstrations say a motion between those poses differs (docs/method.md §12).

    Example: rbgp rollout shoe.rbgp --count 100 --samples 5 -o rollouts.csv

    Example: rbgp rollout shoe.rbgp --start-quat "0 0 0 1 0.4 0 0.2" --goal "0 0 0 1 0.6 0.1 0.3" --samples 20 -o to_goal.csv
    """
    from rbgp_cli import workflows
    from rbgp_cli.errors import InputError
    from rbgp_cli.io.model_store import load_model

    if json_out and (output is None or output == "-"):
        raise InputError("--json prints a summary on stdout, so the CSV needs -o FILE")
    if steps is not None and duration is not None:
        raise InputError("give --steps or --duration, not both")
    if each_duration and not from_demos:
        raise InputError("--each-duration gives each start its demonstration's duration", hint="add --from-demos FILES")
    if each_duration and steps is not None:
        raise InputError("give --each-duration or --steps, not both", hint="--duration sets the starts not drawn near a demonstration")
    if not (math.isfinite(start_time) and 0 <= start_time < 2**31):  # MCAP log times: unsigned; stamps: int32 seconds
        raise InputError(f"start_time must be seconds since the epoch from 0 to {2**31 - 1} (1970 to 2038), got {start_time:g}",
                         param="start_time")
    for name, value in (("duration", duration), ("dt", dt)):  # before the starts are drawn and said
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number of seconds, got {value:g}", param=name)
    from rbgp_cli.dynamics.envelope import OFF_DATA

    if off_data not in OFF_DATA:
        raise InputError(f"off_data must be one of {', '.join(OFF_DATA)}, got {off_data!r}", param="off_data")
    opts = read.options
    if opts.rate is not None and not (starts or from_demos or goals or given):
        raise InputError("--rate is the sample rate of input files without a time column, and rollout reads none here",
                         hint="set the rate of the written trajectories with --output-rate HZ")
    fmt, folder = _rollout_format(output, output_format, mcap_encoding)
    check_files({"--rerun": rerun, "--plot": plot})
    check_outputs(None if folder else (output or "-"), rerun, plot)
    if plot:
        from rbgp_cli.viz.plots import _matplotlib, figure_format

        figure_format(plot)  # a suffix it cannot write: said now
        _matplotlib()  # not installed: say so now, not after the rollout
    m, _ = load_model(model)
    if given:
        if start or start_quat or starts or from_demos or steps is not None or duration is not None or each_duration:
            raise InputError("--given continues motions under way from what was seen: it takes no start poses, "
                             "--steps or --duration", hint="drop them, or drop --given")
        other = [x for x, on in (("an MCAP output", fmt != "csv"), ("--rerun", rerun), ("--plot", plot)) if on]
        if other:
            raise InputError(f"--given writes CSV, and takes no {' or '.join(other)}",
                             hint="write -o FILE.csv (or stdout)" if fmt != "csv" else f"drop {' and '.join(other)}")
        ignored = [flag for flag, on in (("--goal", goal is not None), ("--goals", goals is not None), ("--via", via), ("--goal-tolerance", goal_tolerance),
                                         ("--count", count is not None), ("--dt", dt is not None), ("--output-rate", output_rate is not None),
                                         ("--off-data", off_data != "keep")) if on]
        if ignored:  # a continuation is conditioned on what was seen alone, on its own grid: these would do nothing
            raise InputError(f"--given continues each seen motion on its own; it takes no {', '.join(ignored)}",
                             hint=f"drop {'them' if len(ignored) > 1 else 'it'}, or drop --given")
        return _rollout_given(m, given, read, samples=samples, seed=seed, output=output, json_out=json_out)
    if goal is not None or via or goal_tolerance is not None:  # a mistyped pose (or an empty one) is the one line said
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # said once, below
            for text in [goal] if goal is not None else []:
                workflows.parse_goal(text)
            for text in via or []:
                workflows.parse_via(text)
            if goal_tolerance is not None:
                workflows.parse_tolerance(goal_tolerance)
    q0, p0, durations = workflows.rollout_starts(
        m, start=start, start_quat=start_quat, starts=starts, from_demos=from_demos, count=count,
        start_spread=start_spread, seed=seed, options=opts, max_gap=read.max_gap, each_duration=each_duration,
        duration=duration, progress=progress)
    aims = workflows.goal_options(len(q0), goal=goal, goals=goals, via=via, goal_tolerance=goal_tolerance, options=opts)
    rate = m.recorded_rate if output_rate is None else (output_rate or None)
    res = workflows.rollout_model(m, q0, p0, steps=steps, duration=duration, dt=dt, samples=samples, seed=seed,
                                  with_std=not no_std, progress=progress, durations=durations, rate=rate,
                                  off_data=off_data, **aims)
    trajs = res.trajectories(include_samples=samples > 0)
    if fmt == "csv":
        _write_rollout_csv(res, trajs, output)
    else:
        _write_rollout_mcap(res, trajs, output, folder=folder, encoding=mcap_encoding,
                            frame_id=frame_id or m.provenance.get("frame_id") or "world", start_time=start_time)
    if rerun:
        from rbgp_cli.viz.recording import record_rollout

        record_rollout(rerun, res, up=up)
        progress(f"wrote {rerun}")
    if plot:
        from rbgp_cli.viz.plots import plot_rollout

        plot_rollout(plot, res)
        progress(f"wrote {plot}")
    if json_out:
        n_steps, step = res.integration or (len(res.t) - 1, float(res.t[1] - res.t[0]))
        emit_json({"trajectories": res.count, "samples_per_start": samples, "steps": n_steps, "dt": step,
                   "output_rate_hz": float(rate) if res.integration else 1.0 / step,
                   "durations_s": [float(tr.t[-1]) for tr in trajs[:res.count]],
                   "output": output, "std": res.std is not None, "off_data": off_data, "left_data": res.left,
                   "goal_distance": None if res.goal_distance is None else [float(d) for d in res.goal_distance],
                   "band_widening": None if res.band_widening is None else
                   [{"rotation": float(w[0]), "position": float(w[1])} for w in res.band_widening],
                   "start_beyond": None if res.start_beyond is None else [float(b) for b in res.start_beyond]})


@app.command()
@command
@with_read_options
def follow(
    model: Annotated[str, typer.Argument(help="Model file.")],
    source: Annotated[str, typer.Argument(help="The stream: - for stdin (the default), or a CSV file read row by row to its end.")] = "-",
    every: Annotated[int, typer.Option("--every", min=1, help="Print a prediction every N poses of a motion under way (1: after every pose).")] = 1,
    no_detect: Annotated[bool, typer.Option("--no-detect", help="The stream's first pose is the motion's start (phase 0); by default a motion starts when the pose leaves rest, so follow runs across repetitions.")] = False,
    json_out: Annotated[bool, typer.Option("--json", help="Accepted as every command's --json is: follow prints JSON lines either way.")] = False,
    read: ReadArgs = None,
):
    """Follow a motion live: read poses as CSV rows (stdin, or a file), print one JSON line per prediction.

    The stream is a CSV table (header first, then rows as they arrive: `tail -f` of a logger, or any
    reader's output), read with the read options below. After each pose of a motion under way (or every
    --every poses) one line: t, the motion's start (when it left rest) and how much of the rest before it
    begins it (as the demonstrations begin at rest), its estimated phase, the predicted end time and end
    pose with 90 % bands, whether the motion has left what the demonstrations cover, and whether the
    pose is at rest now (a hold in mid-motion; docs/method.md §13). Nothing is printed at rest before
    a motion starts.

    Example: tail -f take.csv | rbgp follow handover.rbgp
    """
    import contextlib
    import json
    import sys

    from rbgp_cli import workflows
    from rbgp_cli.io.model_store import load_model
    from rbgp_cli.io.stream import open_stream

    m, _ = load_model(model)
    stdin = source == "-"
    if stdin and hasattr(sys.stdin, "buffer"):  # bytes that are not UTF-8 (a binary file piped in) are said, not raised
        import io

        piped = io.TextIOWrapper(sys.stdin.buffer, encoding="utf-8", errors="surrogateescape", newline="")
    else:
        piped = sys.stdin
    with contextlib.nullcontext(piped) if stdin else open_stream(source) as fh:
        for out in workflows.follow_stream(m, iter(fh.readline, ""), options=read.options, every=every,
                                           detect=not no_detect, source="stdin" if stdin else source,
                                           max_gap=read.max_gap, path=None if stdin else source):
            sys.stdout.write(json.dumps(out) + "\n")
            sys.stdout.flush()


def _rollout_given(m, given, read, *, samples, seed, output, json_out) -> None:
    """rollout --given: one continuation per seen motion (CSV), and per motion its estimate in --json."""
    from rbgp_cli import workflows
    from rbgp_cli.io.csv import write_trajectories_csv

    conts = workflows.continue_files(m, given, options=read.options, max_gap=read.max_gap, samples=samples, seed=seed,
                                     progress=progress)
    trajs = [tr for c in conts for tr in c.trajectories(include_samples=samples > 0)]
    # 1 where a row lies outside the demonstrations' envelope at its phase of the whole motion (mean and samples)
    left = [c.info.get("left_data") for c in conts]
    extra = {} if any(x is None for x in left) else {"left_data": [r.astype(float) for x in left for r in x]}
    write_text_output(output, lambda fh: write_trajectories_csv(trajs, fh, extra=extra))
    if json_out:
        emit_json({"output": output, "samples_per_motion": samples,
                   "motions": [dict(trajectory=c.name, source=c.info.get("source"), **c.estimate.to_dict(),
                                    **({} if x is None else {"left_data": bool(x[0].any()),
                                                             "samples_left_data": int(sum(r.any() for r in x[1:]))}))
                               for c, x in zip(conts, left)]})


def _write_rollout_csv(res, trajs, output) -> None:
    """rollout's CSV: the trajectories with the std_<output> and left_data columns (empty for samples)."""
    import numpy as np

    from rbgp_cli.io.csv import write_trajectories_csv

    B = res.count
    extra = {}
    if res.std is not None:
        per = [res.std[b, :res.length(b)] for b in range(B)] + [np.full((len(tr), res.std.shape[2]), np.nan) for tr in trajs[B:]]
        extra = {f"std_{n}": [a[:, j] for a in per] for j, n in enumerate(res.output_names)}
    # 1 where a mean rollout's sample lies outside the demonstrations' envelope (samples: not checked)
    extra["left_data"] = ([res.outside[b, : res.length(b)].astype(float) for b in range(B)]
                          + [np.full(len(tr.t), np.nan) for tr in trajs[B:]])
    write_text_output(output, lambda fh: write_trajectories_csv(trajs, fh, extra=extra))


def _rollout_format(output, output_format, encoding) -> tuple[str, bool]:
    """(csv or mcap, whether -o is a rosbag2 folder), from --output-format or -o's name."""
    import os

    from rbgp_cli.errors import InputError
    from rbgp_cli.io.mcap_out import ENCODINGS

    if output_format not in (None, "csv", "mcap"):
        raise InputError(f"--output-format must be csv or mcap, got {output_format!r}")
    if encoding not in ENCODINGS:
        raise InputError(f"--mcap-encoding must be one of {', '.join(ENCODINGS)}, got {encoding!r}")
    stdout = output is None or output == "-"
    folder = not stdout and (output.endswith(("/", os.sep)) or os.path.isdir(output))
    fmt = output_format or ("mcap" if folder or (not stdout and output.lower().endswith(".mcap")) else "csv")
    if folder:
        if fmt != "mcap":
            raise InputError("is a folder; a CSV needs a file name", path=output)
        if encoding != "ros2":
            raise InputError("a rosbag2 folder holds ROS 2 messages", path=output,
                             hint="write --mcap-encoding foxglove to a .mcap file")
        parent = os.path.dirname(os.path.abspath(output.rstrip("/" + os.sep))) or "."
        if not os.path.isdir(parent) or not os.access(parent, os.W_OK):
            raise InputError("the folder that would hold the rosbag2 folder does not exist or is not writable",
                             path=output)
    return fmt, folder


def _write_rollout_mcap(res, trajs, output, *, folder: bool, encoding: str, frame_id: str, start_time: float) -> None:
    """Write rollout's trajectories (and, in ROS 2 with two samples or more per start, the bands) as MCAP."""
    import math

    from rbgp_cli.errors import InputError
    from rbgp_cli.io.mcap_out import band_covariance, region_covariance, write_rollouts_mcap

    if not math.isfinite(start_time):
        raise InputError(f"--start-time must be a number of seconds, got {start_time!r}")
    bands = {}
    if encoding == "ros2" and res.sample_quat is not None and res.sample_quat.shape[1] >= 2:
        for b in range(res.count):
            n = res.length(b)
            q, p = res.quat[b, :n], res.position[b, :n]
            if res.band_position is not None:  # the next motion's 90 % band, as rbgp computes it
                cov = region_covariance(res.band_position[b, :n], res.band_rotation[b, :n])
            else:  # a model without one (per-step Monte Carlo samples): the samples' spread
                cov = band_covariance(q, p, res.sample_quat[b, :, :n], res.sample_position[b, :, :n])
            bands[b] = (res.t[:n], q, p, cov)
    kwargs = dict(frame_id=frame_id, start_ns=round(start_time * 1e9), encoding=encoding, bands=bands or None)
    if output not in (None, "-"):
        write_rollouts_mcap(trajs, output, folder=folder, **kwargs)
        return
    import io

    buf = io.BytesIO()  # the mcap writer seeks, which a pipe cannot: the whole file, then stdout
    write_rollouts_mcap(trajs, buf, **kwargs)
    sys.stdout.buffer.write(buf.getbuffer())
    sys.stdout.buffer.flush()


# ---------------------------------------------------------------------------------------------- evaluate
@app.command()
@command
@with_read_options
def evaluate(
    generated: Annotated[Optional[List[str]], typer.Argument(help="Generated trajectories (CSV from rbgp rollout, read as rbgp writes it, as are --compare's: the read options apply to --demos; '-' for stdin).")] = None,
    demos: Annotated[Optional[List[str]], paths_option("--demos", help="Demonstration files or folders, several after one flag (e.g. --demos data/*.csv).")] = None,
    model: Annotated[Optional[str], typer.Option("--model", help="Generate --count trajectories from this model like the paper instead.")] = None,
    count: Annotated[int, typer.Option(min=1, help="With --model: number of rollouts from starts near the demonstrations'.")] = 100,
    start_spread: Annotated[float, typer.Option("--start-spread", min=0.0, help="With --model: start perturbation std in metres (rotation: 0.1 rad per 0.3 m), fixed as the paper's protocol.")] = 0.02,
    seed: Annotated[int, typer.Option(min=0, help="With --model: seed of the start perturbations.")] = 0,
    length: Annotated[Optional[int], typer.Option(min=2, help="Resample every trajectory to this many steps (default: the demonstrations' median).")] = None,
    covariance: Annotated[str, typer.Option(help="Per-step Gaussians with diag (mean and variance per dimension) or full covariance.")] = "diag",
    per_step: Annotated[Optional[str], typer.Option("--per-step", help="Write the per-step series to this CSV.")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the scores as JSON on stdout.")] = False,
    rerun: Annotated[Optional[str], typer.Option("--rerun", help="Also write a Rerun recording (.rrd).")] = None,
    plot: Annotated[Optional[str], typer.Option("--plot", help="Also write a figure (PNG, or PDF or SVG by the file's suffix) like the paper's Fig. 4/5: per dimension both sets' mean ± 2σ bands and at most 20 lines of each, axes clipped to the demonstrations and the bulk of the rollouts (clipped ones counted), and the per-step score. With one demonstration there is no score: the figure is still written, without the score panels, and the command exits 2 with the reason.")] = None,
    compare: Annotated[Optional[List[str]], paths_option("--compare", help="With --plot: generated trajectories of a second model (CSV, e.g. the Euler GP's rollouts) drawn in another colour and scored in the distance panel.")] = None,
    up: Annotated[str, typer.Option(help="World up axis for the recording: z or y.")] = "z",
    read: ReadArgs = None,
):
    """Score generated trajectories against demonstrations: per-step Bhattacharyya distance.

    At each step of a common normalised time, the distance between a Gaussian of the generated set
    and one of the demonstrations (rotation relative to the demonstrations' mean rotation, and
    position), averaged over the steps; lower is closer.

    Also says how many generated trajectories left the demonstrations' envelope (where no demonstration
    goes near that phase of the motion; --json: left_data), which a score alone can hide.

    Example: rbgp rollout shoe.rbgp --count 100 -o - | rbgp evaluate - --demos sample_data/csv
    """
    from rbgp_cli import workflows
    from rbgp_cli.errors import InputError

    if not demos:
        raise InputError("no demonstrations given", hint="pass --demos FILE_OR_DIR")
    if covariance not in ("diag", "full"):
        raise InputError(f"--covariance must be diag or full, got {covariance!r}")
    if model is not None and generated:
        raise InputError("give generated trajectories or --model, not both")
    if model is None and not generated:
        from rbgp_cli.cli.args import took_too_much

        hint = took_too_much("generated trajectories", alternative="or give --model MODEL to generate them")
        if hint:
            raise InputError(hint)
    opts, max_gap = read.options, read.max_gap
    if per_step == "-" and json_out:  # stdout holds one thing: the per-step CSV or the JSON
        raise InputError("--json prints a summary on stdout, so the per-step series needs --per-step FILE")
    check_files({"--rerun": rerun, "--plot": plot})
    check_outputs(per_step, rerun, plot)
    if plot:
        from rbgp_cli.viz.plots import _matplotlib, figure_format

        figure_format(plot)  # a suffix it cannot write: said now
        _matplotlib()  # not installed: say so now, not after the scoring
    m = None
    if model is not None:
        from rbgp_cli.io.model_store import load_model

        m, _ = load_model(model)
    result, gen, dem = workflows.evaluate_files(generated or [], demos, options=opts, max_gap=max_gap, length=length,
                                                covariance=covariance, model=m, count=count, spread=start_spread, seed=seed,
                                                progress=progress, unscored=plot is not None)
    refusal = workflows.score_refusal(result)  # only with --plot: the figure is drawn, then the error
    if per_step and not refusal:
        from rbgp_cli.cli.report import write_per_step

        write_text_output(per_step, lambda fh: write_per_step(result, fh))
    if rerun and not refusal:
        from rbgp_cli.viz.recording import record_evaluation

        record_evaluation(rerun, result, gen, dem, up=up)
        progress(f"wrote {rerun}")
    if plot:
        from rbgp_cli.viz.plots import plot_evaluation

        other = None
        if compare:
            other, _, _ = workflows.load_demonstrations(compare)
        from pathlib import Path

        first = (generated or ["-"])[0]
        label = f"{Path(model).stem} rollouts" if model else ("generated" if first == "-" else Path(first).stem)
        plot_evaluation(plot, result, gen, dem, compare=other,
                        labels=(label, Path(compare[0]).stem if compare else "compare"))
        if refusal:
            raise InputError(refusal, hint=f"the figure {plot} was written without a score; pass more demonstrations",
                             param="covariance")
        progress(f"wrote {plot}")
    left = workflows.left_data(gen, dem)  # a score never hides motions that went where no demonstration goes
    if json_out:
        emit_json({**result.to_dict(), "left_data": left})
    else:
        b = result.to_dict()["bhattacharyya"]
        print(f"bhattacharyya mean {b['mean']:.4f}  rotation {b['rotation']:.4f}  translation {b['translation']:.4f}"
              f"  offset {b['offset']:.4f}  spread {b['spread']:.4f}  ({result.steps} steps, {result.n_generated} generated, {result.n_demos} demonstrations)"
              f"; {left['count']} of {left['of']} generated left the demonstrations' envelope",
              file=sys.stderr if per_step == "-" else sys.stdout)  # --per-step -: stdout is the CSV alone


# ---------------------------------------------------------------------------------------------- inspect
@app.command()
@command
@with_read_options
def inspect(
    files: Annotated[List[str], typer.Argument(help="Files to describe ('-' for stdin).")],
    json_out: Annotated[bool, typer.Option("--json", help="Print the description as JSON.")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Full detail for every file (the default for up to 5 files; above that one line per file).")] = False,
    read: ReadArgs = None,
):
    """Describe what files hold (columns or topics, rate, duration, gaps, units) without training.

    Runs train's preparation with the same options and says what it would do: sample-and-hold
    repeats and lost frames dropped, gaps no training pair crosses, breaks that split a take
    (--split-gap), repetitions found with --split-at-rest, a suspect quaternion order. Up to 5 files
    in full, more one line each (-v: in full), then a summary line. Exit code 2 when a file could not
    be read (the others are still described).
    """
    from rbgp_cli.io.inspect import COMPACT_ABOVE, format_compact, format_inspect, format_summary, inspect_file
    from rbgp_cli.workflows import expand_paths

    opts = read.options
    results = [inspect_file(f, opts, max_gap=read.max_gap, words=as_flags) for f in expand_paths(files, opts)]
    for r in results:  # the library names the read options; the command says its flags
        r["needs"] = [need_flags(n) for n in r.get("needs") or []]
        if isinstance(r.get("description"), dict) and r["description"].get("needs"):
            r["description"]["needs"] = [need_flags(n) for n in r["description"]["needs"]]
    if json_out:
        emit_json(results if len(results) != 1 else results[0])
    elif verbose or len(results) <= COMPACT_ABOVE:
        print(flag_words("\n\n".join(format_inspect(r) for r in results)))
    else:
        print(flag_words("\n".join(format_compact(r) for r in results)))
    if len(results) > 1 and not json_out:
        print(("\n" if verbose or len(results) <= COMPACT_ABOVE else "") + format_summary(results))
    unreadable = [r["path"] for r in results if r.get("error")]
    if unreadable:  # described above; the exit code says that not every file could be read
        names = ", ".join(unreadable[:5]) + (f" and {len(unreadable) - 5} more" if len(unreadable) > 5 else "")
        print(f"rbgp: error: {len(unreadable)} of {len(results)} file{'s' * (len(results) != 1)} could not be read: "
              f"{names}", file=sys.stderr)
        raise typer.Exit(2)


# ---------------------------------------------------------------------------------------------- crossval
@app.command()
@command
@with_read_options
def crossval(
    ctx: typer.Context,
    demos: Annotated[List[str], typer.Argument(help="Demonstration files or directories (a shell glob is fine).")],
    folds: Annotated[int, typer.Option(min=2, help="Folds of the demonstrations (a demonstration is never split across folds).")] = 5,
    repeats: Annotated[int, typer.Option(min=1, help="Draw the folds this many times (fold seeds --seed, --seed + 1, ...) and report over all of them, with each repetition's ratio and sample ratio: one set of folds can be lucky (the hand raises' floor moved from 0.17 to 0.38 with the fold seed alone). Costs that many times the fits.")] = 1,
    representation: Annotated[Optional[List[str]], typer.Option("--representation", help="axis-angle, euler, quaternion, or all; repeatable (default: axis-angle).", rich_help_panel=_TRAIN)] = None,
    kernel: Annotated[Optional[List[str]], typer.Option("--kernel", help="Repeatable; every representation runs with every kernel (default: each representation's own). " + kernel_help(), rich_help_panel=_TRAIN)] = None,
    grid: Annotated[Optional[List[str]], typer.Option("--grid", metavar="OPTION=V1,V2,...", help="Repeatable: cross-validate every value of a training option, named as its option without the dashes (e.g. --grid prior-gain=3,5,10 --grid inducing=0,512; 'default' is the option's default). Every combination of the grids × representations × kernels is one row, on the same folds; the values are checked as the option checks them; --seed stays the seed of the folds (--grid seed=0,1 varies the training seed only).", rich_help_panel=_TRAIN)] = None,
    order: Annotated[str, typer.Option("--order", help="How the folds hold demonstrations out: 'random' (a seeded permutation), 'recorded' (--folds contiguous blocks in recording order, the order the files are read: names in natural order within a folder, files in the order given; a block's neighbours in time are then not trained on) or 'forward' (the same blocks, each after the first predicted from the demonstrations recorded before it only: what your next session will see; a block with fewer than 3 before it is skipped). The table's 'splits' line lists them.")] = "random",
    train_size: Annotated[Optional[int], typer.Option("--train-size", min=2, help="Train on this many demonstrations and hold out all the others, --folds times: random subsets, or with --order recorded windows of this many consecutive ones with the later ones held out (a small study: --train-size 5); with --order forward each block is predicted from this many just before it (a sliding window).")] = None,
    replay: Annotated[bool, typer.Option("--replay/--no-replay", help="Include the replay peer: the training demonstration with the nearest start, moved rigidly to the new start.")] = True,
    peers: Annotated[bool, typer.Option("--peers/--no-peers", help="Include the ProMP (conditioned on the start) and Cartesian DMP (of the nearest-start demonstration) peers of the movement-primitives package; left out with a note when it is not installed (pip install \"rbgp-cli\\[peers]\").")] = True,
    jobs: Annotated[Optional[int], typer.Option(min=1, help="Worker processes for the fits (default: one per core); 1 runs them in this process.")] = None,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Run the fits on a Dask cluster: the scheduler's address (tcp://host:8786), or 'local' for a LocalCluster of --jobs single-threaded workers. Needs pip install \"rbgp-cli\\[distributed]\"; the results are the same. A fit whose worker dies is run once more, then the run fails naming the fold (also after 30 s with no live worker).")] = None,
    length: Annotated[Optional[int], typer.Option(min=2, help="Resample every trajectory to this many steps for the scores (default: the training demonstrations' median).")] = None,
    covariance: Annotated[str, typer.Option(help="Per-step Gaussians with diag or full covariance (as rbgp evaluate).")] = "diag",
    samples: Annotated[int, typer.Option("--samples", min=0, help="Sampled rollouts per held-out start (as rbgp rollout --samples) for the columns sample (one sample per start scored like score, over the floor) and cov_pos / cov_rot (how often the held-out motion lies inside the samples' 90 % prediction region: 0.90 for honest bands) with the bands' half-widths in --json; 0: none; at least 4 for the coverage.")] = 20,
    given: Annotated[Optional[List[str]], typer.Option("--given", metavar="F|goal", help="What each row is given of a held-out demonstration besides its start. goal: its final pose and duration (rbgp's motion conditioned on both ends, beside the goal-conditioned peers: nearest, the demonstration nearest by start and goal with its end offsets blended in; promp conditioned on start and goal; dmp of the nearest demonstration with the new goal; the table then has end_mm / end_mrad, the mean motions' end errors). F: a motion under way: see each held-out demonstration's first fraction F (0 < F < 1; repeatable: --given 0.2 --given 0.6) and predict the rest without its duration (docs/method.md §13). Rows per F: rbgp, its path distribution alone (no-GP), the nearest demonstration time-scaled and matched on the seen part, and a ProMP with phase estimation conditioned on the seen part, plain and ridge-regularised; columns final-pose error, end-time error, the remainder's RMSE and the 90 % bands' coverage of it.")] = None,
    without_gp: Annotated[bool, typer.Option("--without-gp/--no-without-gp", help="Beside every model row with a prior mean, a row of the same fits with the GP's residual switched off (kernel column 'no-GP'): the path distribution alone, rolled out from the same starts with the same draws, so the difference is what the GP adds on your data.")] = True,
    per_fold: Annotated[bool, typer.Option("--per-fold", help="Also print one line per fold and configuration.", rich_help_panel=_OUT)] = False,
    json_out: Annotated[bool, typer.Option("--json", help="Print the results as JSON on stdout.", rich_help_panel=_OUT)] = False,
    rho_rot: RhoOpt = _D["rho_rot"], restarts: RestartsOpt = _D["restarts"], explore_size: ExploreOpt = _D["explore_size"],
    seed: SeedOpt = 0, noise: NoiseOpt = "learn", share_hyperparameters: ShareOpt = False,
    subsample: SubsampleOpt = _D["subsample"], max_points: MaxPointsOpt = _D["max_points"],
    time_input: TimeInputOpt = _D["time_input"], prior: PriorOpt = _D["prior"], prior_gain: PriorGainOpt = _D["prior_gain"],
    train_rate: TrainRateOpt = _D["train_rate"], smooth_window: SmoothWindowOpt = _D["smooth_window"],
    smooth_degree: SmoothDegreeOpt = _D["smooth_degree"], inducing: InducingOpt = None,
    hyper_points: HyperPointsOpt = None, calibrate_noise: CalibrateOpt = _D["calibrate"],
    start_conditioning: StartCondOpt = _D["start_conditioning"], noise_scale: NoiseScaleOpt = _D["noise_scale"],
    pull_profile: PullProfileOpt = _D["pull_profile"], residual_gain: ResidualGainOpt = _D["residual_gain"],
    read: ReadArgs = None,
):
    """Cross-validate by demonstration: how well generated motions hold up from start poses the model has
    not seen.

    Train on the other folds (with exactly the options of rbgp train), roll out from
    each held-out demonstration's start for its duration, and score against the training
    demonstrations next to the floor (the held-out demonstrations' own score) and the peers: replay,
    and a ProMP and a DMP from the field's own library (movement-primitives, optional). The left column
    counts the rollouts that left the training demonstrations' envelope.

    Example: rbgp crossval sample_data/csv --representation all --folds 3

    Example: rbgp crossval sample_data/csv --grid prior-gain=3,10 --grid inducing=0,48

    Example: rbgp crossval sample_data/csv --given goal --folds 3
    """
    from rbgp_cli import workflows
    from rbgp_cli.cli.train_options import grid_variants
    from rbgp_cli.errors import InputError, warn

    opts, max_gap = read.options, read.max_gap
    kwargs = train_kwargs(rho_rot=rho_rot, restarts=restarts, explore_size=explore_size, seed=seed, noise=noise,
                          share_hyperparameters=share_hyperparameters, subsample=subsample, max_points=max_points,
                          train_rate=train_rate, smooth_window=smooth_window, smooth_degree=smooth_degree,
                          time_input=time_input, prior=prior, prior_gain=prior_gain, inducing=inducing,
                          hyper_points=hyper_points, calibrate_noise=calibrate_noise,
                          start_conditioning=start_conditioning, noise_scale=noise_scale,
                          pull_profile=pull_profile, residual_gain=residual_gain)
    goal = None
    if given and any(str(v).strip().lower() == "goal" for v in given):
        if len(given) > 1:
            raise InputError("--given goal cannot be combined with other --given values", hint="run crossval once per kind")
        goal = given[0]
    elif given:
        return _crossval_given(demos, given, kwargs, read, folds=folds, seed=seed, samples=samples, peers=peers,
                               json_out=json_out, grid=grid, representation=representation, kernel=kernel,
                               repeats=repeats, order=order, train_size=train_size)
    variants, lists = grid_variants(ctx, grid)
    for name, listed in (("representation", representation), ("kernel", kernel)):
        if name in lists and listed:
            raise InputError(f"give --{name} or --grid {name}=..., not both")
    configs, skipped = workflows.crossval_configs(lists.get("representation", representation), lists.get("kernel", kernel),
                                                  kwargs, replay=replay, peers=peers,
                                                  variants=variants if grid else None)
    for note in skipped:
        warn(f"left out {note}")
    result = workflows.crossval_files(demos, configs, options=opts, max_gap=max_gap, folds=folds, seed=seed, jobs=jobs,
                                      length=length, covariance=covariance, progress=progress, scheduler=scheduler,
                                      samples=samples, repeats=repeats, without_gp=without_gp, order=order,
                                      train_size=train_size, **workflows.given_option(goal))
    result["skipped"] = list(skipped)
    if json_out:
        emit_json(result)
    else:
        from rbgp_cli.cli.report import format_crossval

        print(format_crossval(result, per_fold=per_fold))


def _crossval_given(demos, given, kwargs, read, *, folds, seed, samples, peers, json_out, grid, representation, kernel,
                    repeats=1, order="random", train_size=None):
    """crossval --given F: a motion under way (rbgp_cli.evaluation.under_way)."""
    from rbgp_cli import workflows
    from rbgp_cli.errors import InputError

    fractions = []
    for v in given:
        try:
            fractions.append(float(v))
        except ValueError:
            raise InputError(f"--given takes goal or a seen fraction F between 0 and 1, got {v!r}", hint="e.g. --given goal, or --given 0.2 --given 0.6") from None
    if grid or representation or kernel:
        raise InputError("--given runs the default representation and kernel", hint="drop --grid, --representation and --kernel")
    result = workflows.crossval_under_way(demos, fractions, kwargs, options=read.options, max_gap=read.max_gap, folds=folds,
                                          seed=seed, samples=samples, progress=progress, peers=peers, repeats=repeats,
                                          order=order, train_size=train_size)
    if json_out:  # a method without samples (nearest) has no coverage: emit_json writes it as null
        emit_json(result)
    else:
        from rbgp_cli.cli.report import format_under_way

        print(format_under_way(result))


# ---------------------------------------------------------------------------------------------- demo
@app.command()
@command
def demo(
    out: Annotated[str, typer.Option("--out", help="Directory for the models, rollouts and per-step scores.")] = "rbgp-demo",
    count: Annotated[int, typer.Option(min=1, help="Rollouts per representation.")] = 100,
    representations: Annotated[str, typer.Option(help="Comma-separated representations to compare.")] = "axis-angle,euler,quaternion",
    quick: Annotated[bool, typer.Option("--quick", help="A fast smoke run: at most 200 points, shared hyperparameters.")] = False,
    json_out: Annotated[bool, typer.Option("--json", help="Print the scores as JSON on stdout.")] = False,
):
    """Run the main job on the bundled sample data: train → rollout → evaluate for each representation,
    and print the Bhattacharyya scores (lower is closer to the demonstrations)."""
    from rbgp_cli.demo import run_demo

    check_files({"--out": out}, what="folder")

    scores = run_demo(out, count=count, representations=[r.strip() for r in representations.split(",") if r.strip()],
                      quick=quick, progress=progress)
    if json_out:
        emit_json(scores)
    else:
        print(f"{'representation':<14} {'mean':>8} {'rotation':>9} {'translation':>12}  train_s  rollout_s")
        for rep, s in scores["representations"].items():
            b = s["bhattacharyya"]
            print(f"{rep:<14} {b['mean']:8.3f} {b['rotation']:9.3f} {b['translation']:12.3f}  {s['train_seconds']:7.1f}  {s['rollout_seconds']:9.1f}")


# ---------------------------------------------------------------------------------------------- bench
bench_app = typer.Typer(help="Benchmarks that measure published claims on this machine.", no_args_is_help=True)
app.add_typer(bench_app, name="bench")


@bench_app.command("paper")
@command
def bench_paper(
    part: Annotated[str, typer.Argument(help="all, theorem, runtime or accuracy.")] = "all",
    quick: Annotated[bool, typer.Option("--quick", help="A smoke run of a few seconds (2 repetitions, no 200-rotation sets).")] = False,
    repeats: Annotated[Optional[int], typer.Option(min=1, help="Repetitions of each part: random rotation sets per size, timing runs, random dynamics (default 50; 2 with --quick).")] = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of every random draw.")] = 0,
    json_out: Annotated[bool, typer.Option("--json", help="Print the results as one JSON object on stdout.")] = False,
    markdown: Annotated[Optional[str], typer.Option("--markdown", help="Also write the report as Markdown to this file.")] = None,
):
    """Measure the paper's Theorem 1 and its sec. 4.1 (speed) and 4.2 (accuracy) claims with rbgp's GP.

    Each part runs alone too; statistics over repetitions, BLAS single-threaded for the timings.

    Example: rbgp bench paper --repeats 100 --markdown paper.md
    """
    from rbgp_cli.bench.paper import PARTS, format_report, run_paper_bench
    from rbgp_cli.errors import InputError

    if part not in ("all", *PARTS):
        raise InputError(f"unknown part {part!r}; expected all, {', '.join(PARTS)}")
    check_files({"--markdown": markdown})  # the report (or the JSON) is on stdout already
    check_outputs(markdown)
    res = run_paper_bench(PARTS if part == "all" else (part,), repeats=repeats, seed=seed, quick=quick, progress=progress)
    report = format_report(res)
    if markdown:
        write_text_output(markdown, lambda fh: fh.write(report))
    if json_out:
        emit_json(res)
    else:
        print(report, end="")


def main() -> None:
    """Console-script entry point (``rbgp_cli.__main__.main`` installs the signal handling before
    importing this module; here again for callers of this function). A run that a signal ended
    leaves without the C-level teardown (:func:`rbgp_cli.cli.end_signalled_run`)."""
    from rbgp_cli.cli import SIGNAL_EXITS, end_signalled_run, exit_on_signals

    exit_on_signals()
    try:
        app()
    except SystemExit as exc:
        if exc.code in SIGNAL_EXITS:
            end_signalled_run(exc.code)
        raise
