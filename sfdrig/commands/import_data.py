"""`sfdrig import`: turn measured data from elsewhere (CSV, .mat, TDMS) into a run file."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rig_model.params import RigParamsError, load_rig_params
from sfdrig.commands._batch import run_each
from storage import open_run
from storage.errors import ImportDataError
from storage.importers import CANONICAL, import_file, parse_assignments, parse_scale
from storage.importers.conditions import MOTIONS, Conditions, resolve_conditions
from storage.layout import KINDS

NAME = "import"
HELP = "import measured data (CSV, MATLAB .mat, NI TDMS) into a run file, all or nothing"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, nargs="+",
                        help="measured data: .csv/.txt, .mat or .tdms (several: --out is a folder)")
    parser.add_argument("--out", type=Path, required=True,
                        help="run file to create (.h5), or a folder for several files")
    parser.add_argument(
        "--map", action="append", default=[], metavar="CANONICAL=COLUMN",
        help="use COLUMN (CSV column, .mat variable or NAME(:,COL), TDMS [GROUP/]CHANNEL) as "
             f"CANONICAL, one of {', '.join(CANONICAL)}; repeatable",
    )
    parser.add_argument("--fs", type=float, default=None, metavar="HZ",
                        help="sample rate [Hz] when the file carries none (time column, MAT Fs, "
                             "TDMS wf_increment)")
    parser.add_argument("--freq-hz", type=float, default=None, metavar="HZ",
                        help="excitation frequency of the whole record [Hz], for a file "
                             "without a frequency (freq_hz) or step column: its dwells are "
                             "found at HZ")
    parser.add_argument("--no-steps", action="store_true",
                        help="import a record without dwells (no frequency or step column, e.g. "
                             "a system-identification record): it has no steps, so identify "
                             "cannot use it; diagnose judges it in blocks. Without this, such "
                             "a file is refused")
    parser.add_argument("--scale", action="append", default=[], metavar="CANONICAL=FACTOR",
                        help="multiply a signal by FACTOR (e.g. x_m=1e-6 for micrometres)")
    oil = parser.add_mutually_exclusive_group()
    oil.add_argument("--lubricated", dest="lubricated", action="store_const", const=True,
                     default=None, help="the film was full of oil (lubricated analysis)")
    oil.add_argument("--dry", dest="lubricated", action="store_const", const=False,
                     help="no oil in the film (dry analysis)")
    parser.add_argument("--motion", choices=MOTIONS, default=None,
                        help="motion of every dwell (default: inferred per dwell from the x/y "
                             "phase, printed and stored as inferred)")
    parser.add_argument("--seal", default=None, metavar="none|unknown|F_MU",
                        help="the end seal: none, unknown (identify fits F_mu or takes it from a "
                             "dry run) or its friction force [N]")
    parser.add_argument("--rig", type=Path, default=None, metavar="FILE",
                        help="rig description (TOML, as RigParams.to_toml writes), stored as the "
                             "run's rig_config; its seal is the run's seal unless --seal says")
    parser.add_argument("--conditions", type=Path, default=None, metavar="FILE",
                        help="conditions file (TOML: lubricated, motion, seal, rig); default: "
                             "DATA.conditions.toml or conditions.toml beside the data")
    parser.add_argument("--kind", default="imported", choices=KINDS, help="kind of test")
    parser.add_argument("--notes", default="", help="free-text notes stored in the run")
    parser.add_argument("--operator", default="", help="who measured or imported it")
    parser.add_argument("--run-id", default=None, help="run id (default: imported-<time>-<out>)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")


def _rig_config(cond: Conditions) -> dict[str, object] | None:
    """The rig file validated by the rig model; its seal fills an unstated seal."""
    if cond.rig_file is None:
        return None
    try:
        params = load_rig_params(cond.rig_file)
    except (RigParamsError, ValueError, OSError) as err:
        raise ImportDataError(f"--rig {cond.rig_file}: {err}") from None
    if not cond.seal:
        cond.seal = (repr(params.seal.friction_force_n) if params.seal.enabled
                     and params.seal.friction_force_n > 0 else "none")
        cond.sources["seal"] = f"rig file {cond.rig_file}"
    return dict(params.model_dump(mode="json"))


def _import_one(args: argparse.Namespace, path: Path, out: Path) -> Path:
    cond = resolve_conditions(path, lubricated=args.lubricated, motion=args.motion,
                              seal=args.seal, rig_file=args.rig,
                              conditions_file=args.conditions)
    rig = _rig_config(cond)
    return import_file(
        path, out, mapping=parse_assignments(args.map, "--map"), fs_hz=args.fs,
        scale=parse_scale(args.scale), kind=args.kind, notes=args.notes,
        operator=args.operator, run_id=args.run_id if len(args.file) == 1 else None,
        overwrite=args.overwrite, conditions=cond, rig_config=rig,
        dwell_freq_hz=args.freq_hz, require_steps=not args.no_steps,
    )


def run(args: argparse.Namespace) -> int:
    files: list[Path] = args.file
    if args.no_steps and args.freq_hz is not None:
        print("error: --no-steps and --freq-hz contradict each other: give one", file=sys.stderr)
        return 2
    if len(files) > 1 and not args.out.is_dir():
        print(f"error: --out {args.out}: several files need an existing folder", file=sys.stderr)
        return 2

    def one(path: Path) -> None:
        out = args.out / (path.stem + ".h5") if args.out.is_dir() else args.out
        _print_summary(_import_one(args, path, out))

    failed = run_each(files, one, (ImportDataError,))
    return 2 if failed else 0


def _print_summary(out: Path) -> None:
    with open_run(out) as run_data:
        n_steps = len(run_data.steps)
        print(f"{out}: run {run_data.run_id!r}, {run_data.n_samples} samples at "
              f"{run_data.sample_rate_hz:g} Hz ({run_data.duration_s:.3f} s), channels "
              f"{', '.join(run_data.channel_names)}, {n_steps} "
              f"step{'' if n_steps == 1 else 's'}")
        spec = run_data.test_spec or {}
        restored = run_data.attrs.get("imported_from", "")
        lubricated = bool(run_data.attrs.get("lubricated", False))
    if restored:
        _print_restored(json.loads(restored), lubricated)
        return
    cond = spec.get("conditions", {})
    src = cond.get("sources", {})
    lub = cond.get("lubricated")
    said = "yes" if lub else "no" if lub is False else "not stated (stored as dry)"
    print(f"  lubricated: {said} [{src.get('lubricated', 'not stated')}]")
    seal = cond.get("seal") or "not stated"
    print(f"  seal: {seal} [{src.get('seal', 'not stated')}]")
    if cond.get("rig_file"):
        print(f"  rig_config: {cond['rig_file']} [{src.get('rig')}]")
    per_step = cond.get("motion_per_step", [])
    inferred = [m for m in per_step if str(m["source"]).startswith("inferred")]
    if inferred:
        counts: dict[str, int] = {}
        for m in inferred:
            counts[m["motion"]] = counts.get(m["motion"], 0) + 1
        desc = ", ".join(f"{k} for {v} dwell(s)" for k, v in counts.items())
        print(f"  motion inferred from the x/y phase (stored as inferred): {desc}")
    elif per_step:
        print(f"  motion: {per_step[0]['motion']} [{src.get('motion')}]")
    if not n_steps and not spec.get("sweeps"):
        print("  no steps: sfdrig diagnose judges the record in blocks; sfdrig identify needs "
              "steps (import with the frequency: --map freq_hz=COLUMN or --freq-hz HZ)")
    for sw in spec.get("sweeps", []):
        print(f"  sine sweep {sw['f_start_hz']:g}-{sw['f_stop_hz']:g} Hz (samples "
              f"{sw['first_sample']}-{sw['last_sample']}), not a dwell")
    for note in spec.get("derived", []):
        print(f"  {note}")


def _print_restored(origin: dict[str, object], lubricated: bool) -> None:
    """What a restored sfdrig export is: whose run, which samples, its conditions."""
    print(f"  restored from an sfdrig export ({origin.get('export_format')}) of run "
          f"{origin.get('run_id')!r}, from its sample {origin.get('first_sample')}: channels, "
          "steps, harmonics, events and conditions as exported")
    changed = origin.get("conditions_changed") or {}
    if isinstance(changed, dict) and "lubricated" in changed:
        was = changed["lubricated"]
        print(f"  lubricated: {'yes' if lubricated else 'no'} [{was.get('source')}; the export "
              f"said {'yes' if was.get('export') else 'no'}]")
    else:
        print(f"  lubricated: {'yes' if lubricated else 'no'} [export]")
