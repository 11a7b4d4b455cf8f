"""Human-readable summaries for stderr and the per-step CSV of ``rbgp evaluate``."""

from __future__ import annotations

import math

__all__ = ["format_train_summary", "format_model_info", "write_per_step", "format_crossval"]


def _noise_factors(cal: dict) -> str:
    """What scaled an output's σn² in the posterior: the noise scale (``extra_factor``) and the
    calibration by held-out demonstrations (its record has their ``errors``; a record made by the noise
    scale alone has neither), e.g. ``σn² × 256 noise scale × 16 by held-out demonstrations``."""
    parts = []
    if cal.get("extra_factor", 1.0) != 1.0:
        parts.append(f"× {cal['extra_factor']:g} noise scale")
    if "errors" in cal or cal.get("factor", 1.0) != 1.0:
        parts.append(f"× {cal['factor']:.3g} by held-out demonstrations")
    return "σn² " + " ".join(parts or ["× 1"])


def _fmt_values(values: dict) -> str:
    short = {"signal_std": "σf", "length_scale": "λ", "rho_rot": "ρ1", "noise_std": "σn", "time_scale": "λτ"}
    return "  ".join(f"{short.get(k, k)}={v:.4g}" for k, v in values.items())


def format_train_summary(s: dict) -> str:
    """Demos, pairs, points used, hyperparameters and NLML per output, safeguards, time."""
    lines = [
        f"model: {s.get('model', '')}  ({s['representation']}, kernel {s['kernel']}"
        + (f", rotation metric {s['rotation_metric']}" if s.get("rotation_metric") else "") + ")",
        f"demonstrations: {s['demos']}   pairs: {s['pairs']}   training points: {s['points']}"
        f"   hyperparameters: {'shared' if s['shared_hyperparameters'] else 'per output'}",
    ]
    vel = s.get("velocity")
    if vel:
        how = (f"local polynomial (degree {vel['degree']}) over {vel['window_s']:g} s" if vel["method"] == "local-polynomial"
               else "forward differences")
        grid = f"resampled to {vel['rate_hz']:g} Hz" if vel.get("rate_hz") else "at the recorded samples"
        drift = vel.get("integration_drift") or {}
        lines.append(f"velocities: {how}, {grid}; {vel['segments']} gap-free segments; integrating them back strays "
                     f"≤ {drift.get('max_position_m', 0):.2g} m, {drift.get('max_rotation_rad', 0):.2g} rad")
    if s.get("time_input") or s.get("prior"):
        prior = s.get("prior")
        what = {"path": "the demonstrations' mean path", "goal": "a pull toward the mean final pose"}
        per = "per unit phase" if s.get("time_input") == "phase" else "per second"
        lines.append(f"time input: {s.get('time_input') or 'none'}   prior mean: "
                     + (f"{what[prior['kind']]} (gain {prior['gain']:g} {per}" + (
                         f", up to {prior['gain_max']:.3g} where the demonstrations converge" if prior.get("gain_max") else "")
                        + ")" if prior else "zero"))
    if s.get("variation"):
        lines.append(_variation_text(s["variation"]))
    if s.get("paths"):
        lines.append(_paths_text(s["paths"]))
    if s.get("residual_gain"):
        lines.append(_residual_gain_text(s["residual_gain"]))
    gp = s.get("gp") or {}
    if gp.get("type") == "sparse":
        lines.append(f"sparse GP, {gp['inducing']} inducing poses (NLML column: the negative variational bound): {gp['reason']}")
    elif gp.get("reason"):
        lines.append(f"exact GP: {gp['reason']}")
    for o in s["outputs"]:
        flags = []
        if o["jitter"] > 0:
            flags.append(f"jitter {o['jitter']:.2g}")
        if not o["positive_definite"]:
            flags.append("not PD without jitter")
        if o["at_bounds"]:
            flags.append("at bound: " + ",".join(o["at_bounds"]))
        if o.get("guarded"):
            flags.append("refit with the noise margin (indefinite kernel)")
        if o["n_infeasible"]:
            flags.append(f"{o['n_infeasible']}/{o['n_evaluations']} evaluations infeasible")
        if o.get("calibration"):
            cal = o["calibration"]
            flags.append(f"{_noise_factors(cal)} (fitted σn={cal['noise_std_fitted']:.4g})")
        lines.append(f"  {o['output']:<7} NLML {o['nlml']:11.4g}  {_fmt_values(o['values'])}" + (f"  [{'; '.join(flags)}]" if flags else ""))
    explored = [o["subsample"] for o in s["outputs"] if o.get("subsample")]
    if explored:
        lines.append(f"optimiser: starts explored a random subset of {explored[0]['size']} points first "
                     f"({sum(e['evaluations'] for e in explored)} evaluations there, "
                     f"{sum(o['n_evaluations'] for o in s['outputs'])} on all points; --explore-size 0 turns this off)")
    sg = s["safeguards"]
    lines.append(
        f"safeguards: {'all covariances positive definite' if sg['all_positive_definite'] else 'jitter was needed'}"
        f", {sg['infeasible_evaluations']} infeasible evaluations rejected"
        + (f", refit with the noise margin: {', '.join(sg['refit_with_noise_margin'])}" if sg.get("refit_with_noise_margin") else "")
    )
    lines.append(f"time: {s['seconds']:.1f} s")
    return "\n".join(lines)


def _value(v) -> str:
    """A header value as text people read: nested mappings as ``(key value, ...)``, lists joined by
    commas, None as ``-``, booleans yes/no, floats to 4 digits (never a Python repr)."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        return "(" + ", ".join(f"{k} {_value(x)}" for k, x in v.items()) + ")" if v else "-"
    if isinstance(v, (list, tuple)):
        return ", ".join(_value(x) for x in v) or "-"
    return str(v)


def _variation_text(v: dict) -> str:
    """The lines on the deviation process that --samples draws (docs/method.md §11): its factors, how
    they were found, and the demonstrations' drift over the recording order."""
    line = (f"samples: typical draws of the {v['demos']} demonstrations' deviations from the mean path; bands: the "
            f"next motion's 90 % region (Student-t, ν = {v['demos'] - 2})")
    if v.get("shrinkage"):
        line += f", their covariance between coordinates shrunk by {v['shrinkage']:.2f}"
    scale = v.get("band_scale")
    cal = v.get("calibration") or {}
    if scale:
        how = ("the demonstrations left out at random and in blocks in recording order" if cal.get("recorded")
               else "the demonstrations left out" if cal.get("random") or "calibration" not in v
               else None)
        line += (f"; widened ×{scale['rotation']:.3g} in rotation, ×{scale['position']:.3g} in position so that "
                 f"{how} fall inside them" if how else
                 f"; too few demonstrations ({v['demos']}) to calibrate the bands by leaving them out: "
                 "their width rests on the Student-t alone")
        if cal.get("recorded") and cal.get("random"):
            line += (f" (at random ×{cal['random'][0]:.3g}, ×{cal['random'][1]:.3g}; in recording order "
                     f"×{cal['recorded'][0]:.3g}, ×{cal['recorded'][1]:.3g})")
    sw = cal.get("start_widening")
    parts = [name for name in ("rotation", "position") if sw and sw.get(name)]
    if parts:  # dynamics/variation.band_calibration: the start's surprise kept where it narrows the left-out bands
        line += ("\na start less like the demonstrations' starts than three in four of theirs widens its bands ("
                 + " and ".join(parts) + "): on the demonstrations left out they are "
                 + ", ".join(f"{100 * (1 - r):.0f} % narrower in {n}" for n, r in zip(("rotation", "position"),
                                                                                   sw["mean_width_ratio"]) if sw.get(n))
                 + " on average with it")
    drift = v.get("drift")
    if "drift" in v and drift is None:
        line += (f"\nwith {v['demos']} demonstrations a drift over the recording order cannot be tested (6 or more "
                 "are needed): the bands are for demonstrations like these, not for a session that differs")
    if drift and drift.get("drift"):
        d0, d1 = drift["duration_s"]
        line += ("\nthe demonstrations drift over the recording order (the order they were read): from the first "
                 f"to the last the mean path moves up to {100 * drift['position_m']:.1f} cm (at phase "
                 f"{drift.get('position_phase', 0):.2f}) and {math.degrees(drift['rotation_rad']):.1f}°, the start "
                 f"{100 * drift['start_m']:.1f} cm, the duration {d0:.2f} → {d1:.2f} s (p = {drift['p_value']:.3g}, "
                 "a permutation test); a later session may differ as much or more: the bands are calibrated on "
                 "blocks left out in recording order, which need not cover takes recorded after all of these "
                 "(measure it: rbgp crossval --order forward; with --train-size N, from the latest N takes only, which "
                 "may predict a drifting task's next session better than all of them)")
    return line


def _residual_gain_text(r: dict, gain=None) -> str:
    """The gain on the GP's residual mean (``summary["residual_gain"]``, dynamics/residual_gain.py): how it
    was set and, when chosen, the left-out rollouts' relative errors per gain."""
    from rbgp_cli.dynamics.residual_gain import EQUIVALENT_FRACTION

    r = r if isinstance(r, dict) else {}  # a model file's summary is free-form: shown as far as it makes sense
    try:
        g = float(r.get("gain", 1.0) if gain is None else gain)
    except (TypeError, ValueError):
        g = 1.0
    line = f"GP residual gain: {g:g}"
    try:
        if r.get("chosen") == "left-out rollouts" and r.get("grid"):
            errs = ", ".join(f"{float(x):g}: {float(e):.3f}" for x, e in zip(r["grid"], r.get("error", [])))
            model = "the GP and mean path that have" if r.get("prior") == "left out" else "the GP that has"
            line += (f", chosen by rolling out each of {r.get('demos', '?')} demonstrations with {model} not "
                     f"seen it (relative error, 1 = without the GP: {errs}; the smaller gain within one standard error"
                     # the equivalence margin came with the standard errors against g = 0 (older files: without)
                     + (f" or {100 * EQUIVALENT_FRACTION:g} %)" if "standard_error_zero" in r else ")"))
            fit = r.get("fit")
            if isinstance(fit, dict) and fit.get("full_fit") is False:  # dynamics/model.py: the gain chosen first
                line = (f"GP residual off (gain {g:g}), " + line.split(", ", 1)[1] + "; the full fit was skipped "
                        f"(hyperparameters from one start on {fit.get('hyper_points', '?')} points), use "
                        "--residual-gain 1 to fit it")
        elif r.get("chosen") == "given":
            line += " (given)"
        elif r.get("reason"):
            line += f" ({_value(r['reason'])})"
    except (TypeError, ValueError, KeyError):
        pass
    return line


def _paths_text(p: dict) -> str:
    """One line on the path distribution that goals, via-points and a seen beginning condition
    (docs/method.md §12)."""
    line = (f"goals and seen motions: the {p['demos']} demonstrations' paths and durations as one Gaussian, "
            f"shrunk toward a smooth process (τ² {p['smooth']:.3g}, length {p['length']:.3g} in phase)")
    scale = p.get("band_scale")
    if scale and (scale["rotation"] > 1.0 or scale["position"] > 1.0):
        line += f"; bands widened ×{scale['rotation']:.3g} in rotation, ×{scale['position']:.3g} in position"
    lam = p.get("duration_evidence")
    if lam is not None and lam < 1.0:  # the end time's band of a motion under way (docs/method.md §13)
        line += (f"; a motion under way's end-time band weighs the seen poses' evidence ×{lam:.3g} (the largest weight "
                 "whose band held the demonstrations left out 9 times in 10, else the smallest tried)")
    if p.get("duration_statistic") == "mode":  # docs/method.md §13, the duration's point estimate
        line += ("; a motion under way's end time is its duration weights' mode (the demonstrations left out were "
                 "timed closer by it than by the median)")
    if p.get("rest_duration_tolerance") is not None:  # docs/method.md §13, the rest's ln D
        line += ("; a motion under way's rest is conditioned without the duration's coupling to the path (the demonstrations left out "
                 "were predicted as well without it)")
    if p.get("rest_near_tolerance") is not None:  # docs/method.md §13, the near pose
        line += (f"; and on the pose just before the last seen one, tolerance {p['rest_near_tolerance']:.3g} spreads (where "
                 "the motion is heading: the demonstrations left out, their durations estimated, were predicted better with it)")
    return line


def _kernel_text(k) -> str:
    if not isinstance(k, dict):
        return _value(k)
    rest = {key: v for key, v in k.items() if key != "kind"}
    return f"{k.get('kind', '?')} {_value(rest)}" if rest else str(k.get("kind", "?"))


def format_model_info(path: str, h: dict) -> str:
    s = h.get("summary", {})
    prov = h.get("provenance", {})
    lines = [
        f"{path}: {h['format']} version {h['version']}, written by rbgp {h.get('rbgp_version', '?')} at {h.get('created', '?')}",
        f"representation: {h['representation'].get('name')}   kernel: {_kernel_text(h['kernel'])}",
        f"inputs: {', '.join(h.get('input_names', []))}   outputs: {', '.join(h.get('output_names', []))}",
        f"training points: {h.get('training_points', '?')}   time step: {h['dt']:.6g} s   shared hyperparameters: {_value(h['shared'])}",
    ] + ([f"sparse GP: {h['gp']['inducing']} inducing poses (NLML: the negative variational bound)"]
         if (h.get("gp") or {}).get("type") == "sparse" else []) + (
        [_variation_text({**(s.get("variation") or {}), **h["variation"]})] if h.get("variation") else []) + (
        [_paths_text(h["paths"])] if h.get("paths") else []) + (
        [_residual_gain_text(s.get("residual_gain") or {}, h.get("residual_gain", 1.0))]
        if "residual_gain" in h or s.get("residual_gain") else [])
    names = ["all"] if h["shared"] else h.get("output_names", [])
    for nm, f in zip(names, h["fits"]):
        cal = f.get("calibration")
        lines.append(f"  {nm:<7} NLML {f['nlml']:11.4g}  {_fmt_values(f['values'])}  jitter {f['jitter']:.2g}"
                     + (f"  [{_noise_factors(cal)}; fitted σn={cal['noise_std_fitted']:.4g}]" if cal else ""))
    for inp in prov.get("inputs", []):
        lines.append(f"input: {inp.get('name')}  sha256 {inp.get('sha256', '-')[:16]}…")
    if prov.get("train_options"):
        lines.append("options: " + ", ".join(f"{k}={_value(v)}" for k, v in prov["train_options"].items()))
    if prov.get("read_options"):
        lines.append("read options: " + ", ".join(f"{k}={_value(v)}" for k, v in prov["read_options"].items()))
    demos = prov.get("demonstrations") or []
    if demos:
        durs = [d.get("duration_s") or 0.0 for d in demos]
        lines.append(f"demonstrations: {len(demos)}, {min(durs):.3g}–{max(durs):.3g} s")
    if s.get("seconds") is not None:
        lines.append(f"training took {s['seconds']:.1f} s")
    return "\n".join(lines)


def write_per_step(result, fh) -> None:
    """Columns: step, s (normalised time), bhattacharyya, rotation, translation, offset, spread (the
    total's two parts: the sets' means apart, their spreads unlike; they add up to it); floats as the
    shortest text that reads back to the same float64 (``float.__repr__`` of Python floats: the
    ``repr`` of a numpy scalar is ``np.float64(…)``, which no CSV reader takes for a number)."""
    import numpy as np

    rows = np.column_stack([result.s, result.per_step, result.per_step_rotation, result.per_step_translation,
                            result.per_step_offset, result.per_step_spread])
    fh.write("step,s,bhattacharyya,rotation,translation,offset,spread\n")
    fh.writelines(f"{i}," + ",".join(map(float.__repr__, row)) + "\n"
                  for i, row in enumerate(rows.astype(np.float64).tolist()))


def _num(v, fmt: str = ".3f") -> str:
    return "-" if v is None else format(v, fmt)


def _cov_cell(value, se, width: int) -> str:
    """A coverage and its standard error over the held-out motions, ``0.85±0.03`` (``0.85`` without an SE,
    ``-`` without a coverage), right-aligned in ``width``."""
    if value is None or value != value:
        return f"{'-':>{width}}"
    text = f"{value:.2f}" + ("" if se is None or se != se else f"±{se:.2f}")
    return f"{text:>{width}}"


def _options_label(row: dict) -> str:
    """The --grid options of a crossval row: its label after the representation and kernel."""
    if not row.get("options"):
        return ""
    head = f"{row['representation']} {row['kernel']} "
    label = row.get("label", "")
    return label[len(head):] if label.startswith(head) else " ".join(f"{k}={v}" for k, v in row["options"].items())


def format_crossval(result: dict, per_fold: bool = False) -> str:
    """The cross-validation table (stdout): one row per configuration, best score / floor first."""
    from rbgp_cli.evaluation.crossval import splits_text

    sizes = ", ".join(str(n) for n in result["fold_sizes"])
    R = int(result.get("repeats", 1))
    seeds = f"seed {result['seed']}" if R == 1 else f"{R} repeats (fold seeds {result['seed']}–{result['seed'] + R - 1})"
    folds = (f"{result['folds']} forward folds of {result['blocks']} blocks" if result.get("order") == "forward"
             and result.get("blocks") else f"{result['folds']} folds")
    lines = [
        f"{result['demonstrations']} demonstrations, {folds} ({sizes} held out), {seeds}; "
        f"floor {result['floor']:.3f} (the held-out demonstrations scored against the same training sets)",
        "score: Bhattacharyya distance of the rollouts from the held-out starts to the training demonstrations "
        "(lower is better); ratio = score / floor; pos/rot: RMSE against the held-out demonstration with the "
        "same start (m, rad); vel: relative velocity RMSE on held-out pairs (1 = predicting zero); sample: one "
        "sampled rollout per start scored like score, over the floor; cov_pos/cov_rot: how often the held-out "
        "motion lies inside the samples' 90 % prediction region (0.90 = honest bands) ± its standard error over "
        "the held-out motions; left: rollouts "
        "that left the training demonstrations' envelope; kernel 'no-GP': the same fits with the GP's residual "
        "switched off (the path distribution alone), what the GP adds is the difference"
        + (f" (held-out demonstrations: {result['floor_left_data']} of "
           f"{sum(len(sp['test']) for sp in result['splits']) if result.get('splits') else result['demonstrations'] * R})"
           if result.get("floor_left_data") is not None else ""),
        splits_text(result),
        "",
        f"{'representation':<14} {'kernel':<10} {'score':>8} {'floor':>7} {'ratio':>7} {'rotation':>9} {'translation':>11}"
        f" {'pos_m':>7} {'rot_rad':>7} {'vel':>6} {'sample':>7} {'cov_pos':>9} {'cov_rot':>9} {'train_s':>8} {'left':>5}",
    ]
    goal = result.get("given") == "goal"
    if goal:  # the end errors of the mean motions, after the other columns
        shown = {str(r.get("representation")) for r in result["results"]}  # the peers name their rows so
        said = " ".join(x for k, x in (("promp", "promp: conditioned on start and goal;"),
                                        ("dmp", "dmp: of the nearest demonstration, with the new goal;")) if k in shown)
        lines[1] = ("given goal: each held-out demonstration's start, final pose and duration are given; "
                    "end_mm / end_mrad: how far the mean motions end from that final pose; nearest: the "
                    "demonstration nearest by start and goal with its end offsets blended in; " + said
                    + (" " if said else "") + lines[1])
        lines[-1] += f" {'end_mm':>7} {'end_mrad':>8}"
    # rows of a --grid: the options that make each row, after its numbers
    options = {id(r): _options_label(r) for r in result["results"]}
    if any(options.values()):
        lines[-1] += "  options"

    def row(r, label_rep, label_kern, opts=""):
        flag = "" if r.get("reliable", True) else "  *"
        end = ""
        if goal:
            mm = None if r.get("end_position") is None else 1000.0 * r["end_position"]
            mrad = None if r.get("end_rotation") is None else 1000.0 * r["end_rotation"]
            end = f" {_num(mm, '7.1f'):>7} {_num(mrad, '8.1f'):>8}"
        return (f"{label_rep:<14} {label_kern:<10} {r['score']:8.3f} {r['floor']:7.3f} {r['ratio']:7.2f} {r['rotation']:9.3f}"
                f" {r['translation']:11.3f} {r['position_rmse']:7.3f} {r['rotation_rmse']:7.3f} {_num(r['velocity_rmse'], '6.3f'):>6}"
                f" {_num(r.get('sample_ratio'), '7.2f'):>7} {_cov_cell(r.get('coverage_position'), r.get('coverage_position_se'), 9)}"
                f" {_cov_cell(r.get('coverage_rotation'), r.get('coverage_rotation_se'), 9)}"
                f" {r['train_s']:8.1f} {_num(r.get('left_data'), 'd'):>5}" + end + (f"  {opts}" if opts else "") + flag)

    for r in result["results"]:
        kern = "no-GP" if r.get("without_gp") else r["kernel"] or "-"
        lines.append(row(r, r["representation"], kern, options[id(r)].replace(", without the GP", "").strip(", ")))
        if per_fold:
            for f in r["per_fold"]:
                name = f"  fold {f['fold'] + 1}" if "repeat" not in f else f"  r{f['repeat'] + 1} fold {f['fold'] + 1}"
                lines.append(row(f, name, f"({f['n_test']} held)"))
    if R > 1:
        lines.append("")
        lines.append("per repetition (fold seed: ratio, sample ratio):")
        for r in result["results"]:
            parts = [f"{b['seed']}: {b['ratio']:.2f}, {_num(b.get('sample_ratio'), '.2f')}" for b in r.get("by_repeat", [])]
            lines.append(f"  {r['label']:<24} " + "; ".join(parts) + (f"  {options[id(r)]}" if options[id(r)] else ""))
    if any(not r.get("reliable", True) for r in result["results"]):
        lines.append("* some folds have too few trajectories for their per-step variances (see the warnings)")
    # rows that differ in the GP alone (its representation or kernel) are alike where no fit kept the GP's residual
    gp_rows = [r for r in result["results"] if r.get("kernel") and not r.get("without_gp")]
    gains = [f.get("residual_gain") for r in gp_rows for f in r.get("per_fold", [])]
    off = sum(g == 0 for g in gains)
    if len({(r["representation"], r["kernel"]) for r in gp_rows}) > 1 and gains and 2 * off >= len(gains):
        lines += ["", f"note: {off} of {len(gains)} fits switched the GP's residual off (gain 0, chosen on held-out "
                     "rollouts): there the motion is the path prior's, and rows that differ only in the GP's "
                     "representation or kernel differ little; --residual-gain 1 compares the GPs themselves"]
    lines += _paired_lines(result)
    return "\n".join(lines)


def _paired_cell(p: dict) -> str:
    """``+0.0010 ± 0.0024 z +0.40`` (and `` !`` where |z| ≥ 2) of one paired_difference."""
    if p["difference"] is None:
        return "-"
    if p["z"] is None:
        return f"{p['difference']:+.4f} ± -"
    return f"{p['difference']:+.4f} ± {p['se']:.4f} z {p['z']:+.2f}" + (" !" if abs(p["z"]) >= 2 else "")


def _paired_lines(result: dict) -> list[str]:
    """The section below crossval's table: each row's per-motion RMSEs paired with the reference row's
    (rbgp_cli.evaluation.crossval.paired_difference); nothing without a reference or other rows."""
    rows = [r for r in result["results"] if r.get("paired")]
    ref = result.get("paired_reference")
    if not ref or not rows:
        return []
    n = max(r["paired"]["position"]["motions"] for r in rows)
    width = max(len("row"), *(len(r["label"]) for r in rows))
    lines = ["", f"paired against {ref} on the {n} held-out motions (Δ: the row's RMSE minus the reference's per "
             "motion, mean ± standard error; z = Δ / se, ! where |z| ≥ 2, a difference beyond the motions' scatter; "
             "closer: on how many motions the row is closer, position / rotation):",
             f"  {'row':<{width}}  {'Δpos_m':<26}  {'Δrot_rad':<26}  closer"]
    for r in rows:
        p = r["paired"]
        lines.append(f"  {r['label']:<{width}}  {_paired_cell(p['position']):<26}  {_paired_cell(p['rotation']):<26}"
                     f"  {p['position']['closer']} / {p['rotation']['closer']}")
    return lines


def format_under_way(result: dict) -> str:
    """crossval --given's table: one row per seen fraction and method (rbgp_cli.evaluation.under_way),
    after the line saying which splits it used."""
    from rbgp_cli.evaluation.crossval import splits_text

    head = (f"{'given':>5} {'method':<12} {'end_pos':>8} {'end_rot':>8} {'end_time':>8} {'rest_pos':>8} "
            f"{'rest_rot':>8} {'cov_pos':>9} {'cov_rot':>9} {'cov_end':>9} {'left':>9}")
    folds = f"{result['folds']} {'forward ' if result.get('order') == 'forward' else ''}folds"
    floor = result.get("floor_left_data") or []
    floor_text = "" if not floor else (" (the held-out remainders themselves: " + ", ".join(
        f"{x['left_data']} of {x['left_of']} at {x['given']:g}" for x in floor if x.get("left_of") is not None) + ")")
    lines = [f"a motion under way: {folds}, {result['samples']} samples per motion; "
             "end and rest errors in m / rad / s, coverage of the remainder by the 90 % bands and of the end time "
             "by its 90 % band (cov_end) ± its standard error over the held-out motions; left: the continuations "
             "(means and samples) that leave the training demonstrations' envelope, of those predicted"
             + floor_text] + ([splits_text(result)] if "splits" in result else []) + [head]

    def f(x, w, d):
        return f"{x:>{w}.{d}f}" if x == x else f"{'-':>{w}}"

    for r in result["rows"]:
        left = "-" if r.get("left_of") is None else f"{r['left_data']}/{r['left_of']}"
        lines.append(f"{r['given']:>5g} {r['method']:<12} {f(r['end_pos'], 8, 3)} {f(r['end_rot'], 8, 3)} "
                     f"{f(r['end_time'], 8, 3)} {f(r['rest_pos'], 8, 3)} {f(r['rest_rot'], 8, 3)} "
                     f"{_cov_cell(r['cov_pos'], r.get('cov_pos_se'), 9)} {_cov_cell(r['cov_rot'], r.get('cov_rot_se'), 9)} "
                     f"{_cov_cell(r.get('cov_end_time', float('nan')), r.get('cov_end_time_se'), 9)} {left:>9}")
    return "\n".join(lines + _under_way_paired_lines(result))


def _under_way_paired_lines(result: dict) -> list[str]:
    """The section below crossval --given F's table: each row's per-motion values paired with the
    reference's (rbgp's) at the same F, per column (rbgp_cli.evaluation.under_way.add_paired); nothing
    without paired rows."""
    from rbgp_cli.evaluation.under_way import COLUMNS

    rows = [r for r in result["rows"] if r.get("paired")]
    if not rows:
        return []
    ref = rows[0]["paired"]["reference"]
    n = max(r["paired"][COLUMNS[0]]["motions"] for r in rows)
    lines = ["", f"paired against {ref} at the same F on the {n} held-out motions (Δ: the row's value minus {ref}'s per "
             "motion, mean ± standard error, m / rad / s; z = Δ / se, ! where |z| ≥ 2, a difference beyond the "
             "motions' scatter; closer: on how many motions the row is closer, per column in this order):",
             f"{'given':>5} {'method':<12} " + "  ".join(f"{'Δ' + c:<26}" for c in COLUMNS) + "  closer"]
    for r in rows:
        p = r["paired"]
        lines.append(f"{r['given']:>5g} {r['method']:<12} " + "  ".join(f"{_paired_cell(p[c]):<26}" for c in COLUMNS)
                     + "  " + " / ".join(str(p[c]["closer"]) for c in COLUMNS))
    return lines
