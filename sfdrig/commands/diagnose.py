"""`sfdrig diagnose RUN.h5 [...]`: what the rig model gets wrong, its cause, and the gain.

Thin wiring: the work is `analysis.diagnose`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "diagnose"
HELP = ("replay measured force through the rig model, find which effect explains the "
        "discrepancy, write the extended rig model")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="*", type=Path, metavar="RUN.h5",
                        help="run files (split into training and held-out dwells or blocks); "
                             "or give --train-runs and --test-runs instead")
    parser.add_argument("--train-runs", nargs="+", type=Path, metavar="RUN.h5",
                        help="run files to fit on (whole runs; with --test-runs)")
    parser.add_argument("--test-runs", nargs="+", type=Path, metavar="RUN.h5",
                        help="run files to judge on, never fitted (with --train-runs)")
    parser.add_argument("--rig", type=Path, help="rig TOML overriding the runs' rig_config")
    parser.add_argument("--baseline", choices=("config", "fitted"),
                        help="config: the rig configuration as it stands (default for runs "
                             "recorded on this rig); fitted: mass, damping, stiffness fitted to "
                             "the training data first (default for imported runs)")
    parser.add_argument("--train", metavar="SPANS", help="training sample spans a:b,c:d")
    parser.add_argument("--test", metavar="SPANS", help="held-out sample spans a:b,c:d")
    parser.add_argument("--json", type=Path, metavar="FILE", help="write the result as JSON")
    parser.add_argument("--report", type=Path, metavar="DIR", help="write an HTML report")
    parser.add_argument("--model-out", type=Path, metavar="TOML",
                        help="extended rig model path (default: beside --json/--report, or "
                             "<first run>.extended.toml)")
    parser.add_argument("--effects", metavar="IDS", help="comma-separated effect ids to consider")
    parser.add_argument("--max-effects", type=int, default=3, help="effects to look for (3)")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap seed (0)")
    parser.add_argument("--judge", choices=("response", "force"), default="response",
                        help="response: replay the force through the model and judge the "
                             "response (default); force: predict the force from the measured "
                             "motion (inverse model) and judge the force, for a body without "
                             "a spring or closed-loop data a replay cannot follow")
    parser.add_argument("--cutoff-hz", type=float,
                        help="--judge force: low-pass before differentiating (default: "
                             "100 Hz or a tenth of the sample rate, whichever is lower)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    """The command. What the data or the arguments do not allow is one line (exit 2; the
    internals raise `DiagnoseError` where they know the run, the column or the step), as is a
    file that cannot be written; anything else is a defect, for the CLI to name (exit 70),
    never a traceback."""
    try:
        _select_runs(args)
        return _run(args)
    except _BadArguments as err:
        print(f"sfdrig diagnose: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        raise  # stdout's reader has gone: the CLI stops quietly
    except OSError as err:
        print(f"sfdrig diagnose: {err}", file=sys.stderr)
        return 2


class _BadArguments(ValueError):
    pass


def _select_runs(args: argparse.Namespace) -> None:
    """Check the run arguments; with --train-runs/--test-runs, ``args.runs`` becomes the
    training runs then the held-out runs and ``args.train_index`` the training indices."""
    args.train_index = None
    across = args.train_runs is not None or args.test_runs is not None
    if not across:
        if not args.runs:
            raise _BadArguments("no run files: give RUN.h5 ... or --train-runs A.h5 ... "
                                "--test-runs B.h5 ...")
        return
    if args.runs:
        raise _BadArguments(
            f"run files given both as arguments ({', '.join(map(str, args.runs))}) and with "
            "--train-runs/--test-runs: give them one way")
    if args.train_runs is None or args.test_runs is None:
        given, other = (("--train-runs", "--test-runs") if args.test_runs is None
                        else ("--test-runs", "--train-runs"))
        raise _BadArguments(f"{given} needs {other}: name the runs to judge on as well")
    if args.train or args.test:
        raise _BadArguments("--train/--test sample spans cannot be combined with --train-runs/"
                            "--test-runs (whole runs are the split)")
    if args.judge == "force":
        raise _BadArguments("--train-runs/--test-runs work with --judge response only")
    seen: dict[Path, str] = {}
    for opt, paths in (("--train-runs", args.train_runs), ("--test-runs", args.test_runs)):
        for p in paths:
            key = p.resolve()
            if key in seen:
                if seen[key] == opt:
                    raise _BadArguments(f"{p} is given twice in {opt}")
                raise _BadArguments(f"{p} is given in both --train-runs and --test-runs: "
                                    "held-out runs must never be used for fitting")
            seen[key] = opt
    args.runs = list(args.train_runs) + list(args.test_runs)
    args.train_index = list(range(len(args.train_runs)))


def _run(args: argparse.Namespace) -> int:
    from analysis.diagnose import DiagnoseError, diagnose, load_run, parse_spans
    from analysis.diagnose.baseline import baseline_modes
    from analysis.diagnose.hysteresis import describing_function_text
    from analysis.diagnose.report import (
        baseline_modes_text,
        order_label,
        order_status,
        write_extended_model,
        write_json,
        write_report,
    )
    from rig_model.params import RigParamsError, load_rig_params

    def log(msg: str) -> None:
        if not args.quiet:
            print(msg, file=sys.stderr)

    if args.judge == "force":
        return _run_inverse(args)
    try:
        rig = load_rig_params(args.rig) if args.rig else None
        records = [load_run(p, i) for i, p in enumerate(args.runs)]
        effects = [e.strip() for e in args.effects.split(",")] if args.effects else None
        diag = diagnose(records, args.baseline, parse_spans(args.train, "--train"),
                        parse_spans(args.test, "--test"), rig=rig, seed=args.seed,
                        max_effects=args.max_effects, effects=effects, log=log,
                        train_runs=args.train_index)
    except (DiagnoseError, RigParamsError) as err:
        msg = str(err)
        if not any(Path(p).name in msg for p in args.runs):  # name the files the reason is about
            msg = f"{', '.join(str(p) for p in args.runs)}: {msg}"
        print(f"sfdrig diagnose: {msg}", file=sys.stderr)
        return 2
    if args.model_out:
        model_path = args.model_out
    elif args.json:
        model_path = args.json.with_suffix(".extended.toml")
    elif args.report:
        model_path = args.report / "extended_rig.toml"
    else:
        model_path = args.runs[0].with_suffix(".extended.toml")
    model_path.parent.mkdir(parents=True, exist_ok=True)
    write_extended_model(diag, model_path)
    if args.json:
        write_json(diag, args.json, str(model_path))
    if args.report:
        page = write_report(diag, args.report, str(model_path))
        log(f"report: {page}")
    u = diag.units
    print(f"baseline ({diag.baseline_kind}): held-out RMS error {diag.baseline_rms:.4g} {u}")
    for row in diag.order:
        print(f"  order: {order_label(row)}"
              + (f", held-out {row['held_out_error']:.4g} {u}" if "held_out_error" in row else "")
              + f" ({order_status(row)})")
    for f in diag.findings:
        print(f"found {f.effect} ({f.parameters_text()}): held-out {f.error_before:.4g} -> "
              f"{f.error_after:.4g} {u}, gain {f.gain:.3g} "
              f"[{f.gain_interval[0]:.3g}, {f.gain_interval[1]:.3g}] "
              f"({f.evidence.get('confidence', '')} confidence)")
        for row in f.evidence.get("describing_function", []):
            print("  " + describing_function_text(row))
    if not diag.findings:
        print("no effect of the library explains the residual significantly")
        best = diag.best_candidate()
        if best is not None:
            params = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                               for k, v in best["parameters"].items())
            why = best.get("not_a_finding", "not significant")
            # a gain that rounds to 1 lowers nothing: no candidate is better than the baseline
            lead = ("best candidate" if round(best["gain"], 3) > 1.0 else
                    "no candidate lowers the held-out error; the nearest")
            print(f"  {lead}: {best['effect']} ({params}), held-out "
                  f"{best['held_out_error']:.4g} {u}, gain {best['gain']:.4g} ({why})")
    if diag.unexplained:
        print("unexplained: a structured discrepancy remains that the library does not explain")
    if diag.verdict is not None:
        print(f"verdict: {diag.verdict.text}")
        structure = diag.verdict.structure
        for row in structure[:_STRUCTURE_SHOWN]:
            print(f"  structure above the noise: {row['text']}")
        if len(structure) > _STRUCTURE_SHOWN:
            print(f"  ... and {len(structure) - _STRUCTURE_SHOWN} more tests above the noise "
                  "(JSON verdict.structure)")
        # the whole record: harmonics to 10X, lines between them, the 1X at the noise
        for row in diag.verdict.record:
            print(f"  in the record, not in the model: {row['text']}")
    if diag.amplitude is not None:
        print(f"amplitude dependence: {diag.amplitude.text}")
        for lv in diag.amplitude.levels:
            print(f"  {lv.axis} {lv.label:>14s}: {lv.text}")
        for eff, why in diag.amplitude.contradicted.items():
            print(f"  {eff}: contradicted by the levels: {why}")
    if diag.baseline_kind == "fitted":
        print("baseline's modes (frequency, damping): "
              + baseline_modes_text(baseline_modes(diag.baseline_model, diag.records)))
    if diag.modes is not None:
        print(f"modes in the band: {diag.modes.text}")
        for tr in (t for t in diag.modes.tracks if t.shown):
            trends = (f": {tr.frequency.verdict} ({tr.frequency.change:+.1%}), damping "
                      f"{tr.damping.verdict} ({tr.damping.change:+.0%})"
                      if tr.frequency and tr.damping else "")
            print(f"  {tr.axis} mode {tr.index} over {len(tr.levels)} level(s){trends}")
    print(f"extended model: {model_path}")
    return 0


#: structure rows printed (largest first; the JSON and the report hold them all)
_STRUCTURE_SHOWN = 6


def _run_inverse(args: argparse.Namespace) -> int:
    import json

    from analysis.diagnose import DiagnoseError, load_run, parse_spans
    from analysis.diagnose.inverse import diagnose_inverse
    from analysis.diagnose.report import jsonable

    try:
        records = [load_run(p, i) for i, p in enumerate(args.runs)]
        diag = diagnose_inverse(records, parse_spans(args.train, "--train"),
                                parse_spans(args.test, "--test"), cutoff_hz=args.cutoff_hz,
                                seed=args.seed, max_effects=args.max_effects)
    except DiagnoseError as err:
        print(f"sfdrig diagnose: {err}", file=sys.stderr)
        return 2
    doc = jsonable(diag.to_dict())
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"judged: the force from the measured motion (low-pass {diag.cutoff_hz:.4g} Hz)")
    print("baseline (fitted): " + ", ".join(f"{k}={v:.4g}"
                                            for k, v in diag.baseline_params.items())
          + f"; held-out RMS error {diag.baseline_rms:.4g} N")
    for f in diag.findings:
        params = ", ".join(f"{k}={v:.4g}" for k, v in f.parameters.items())
        print(f"found {f.effect} ({params}): held-out {f.error_before:.4g} -> "
              f"{f.error_after:.4g} N, gain {f.gain:.3g} "
              f"[{f.gain_interval[0]:.3g}, {f.gain_interval[1]:.3g}] "
              f"({f.evidence['confidence']} confidence)")
    v = diag.verdict
    print(f"verdict: {v.text} (held-out signal explained: baseline "
          f"{v.baseline.explained:.3f}, final {v.final.explained:.3f})")
    print("final model: " + ", ".join(f"{k}={x:.4g}" for k, x in diag.final_params.items()))
    return 0
