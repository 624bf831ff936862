"""The sumo-swarm command (``sumo-swarm``, or ``python -m sumo_swarm``).

Exit status: 0 success, 2 bad input (one line on stderr naming the problem, no traceback),
1 anything else.
"""

from __future__ import annotations

import argparse
import importlib.resources
import logging
import math
import re
import signal
import sys
import textwrap
import threading
from pathlib import Path

from sumo_swarm import __version__
from sumo_swarm.checks import SEED_MAX, did_you_mean
from sumo_swarm.controllers import CONTROLLERS
from sumo_swarm.errors import ConfigError, RunInterrupted, SimulationError

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2

DESCRIPTION = (
    "Vehicles swarm intelligence for Eclipse SUMO: a platoon of connected automated vehicles "
    "(CAVs) held up by a slow vehicle overtakes it as a swarm and regroups (Hu et al., "
    '"Vehicles Swarm Intelligence"). Run one scenario, reproduce the paper\'s evaluation, or '
    "sweep many runs."
)
EXIT_STATUS = (
    "exit status: 0 success, 2 bad input (one line naming the problem and the file), "
    "1 anything else. 'sumo-swarm COMMAND --help' explains each command."
)
CONTROLLER_HELP = (
    "how the CAVs are driven: swarm (the paper's method), cacc (the paper's baseline, a "
    "longitudinal-only CACC platoon), sumo-cacc (SUMO's own CACC car-following model, only the "
    "lane changes its route needs), sumo-lc (the CAVs as ordinary SUMO vehicles, each "
    "overtaking on its own) "
    "(default: %(default)s)"
)


def _wrap(text: str) -> str:
    """A paragraph for a help text (the formatter keeps line breaks, so the epilogs' layout)."""
    return textwrap.fill(text, width=92)


def _paper_scenario() -> Path:
    """The paper's scenario installed with the package: every key, its unit and its source."""
    return Path(str(importlib.resources.files("sumo_swarm") / "data" / "paper.toml"))


RUN_EPILOG = f"""\
A scenario file (TOML) has the sections [simulation], [evaluation], [cav], [hv], [scene],
[cell], [grid], [planner], [cacc], [swarm], [longitudinal] and [lateral]; every key has its
unit in its name, and an unknown key or a value out of range is refused. The paper's
scenario, installed with the package, lists every key with its meaning and source:
  {_paper_scenario()}
Copy it anywhere, change what you need and run the copy: a network path that does not
resolve beside the copy falls back to the built-in network of that file name.

With --sumocfg, your own SUMO configuration runs as it is (the sublane model is added if it
lacks one; collisions are counted, not teleported away); the vehicles of vType --cav-type form
the swarm, and --config sets the swarm's settings.

Outputs in --out: summary.json, trajectories.parquet (one row per vehicle per step),
events.jsonl, plans.jsonl (swarm), sumo/ (the SUMO configuration as run: open
sumo/scenario.sumocfg in sumo-gui), run.json (what the folder holds) and, with --fcd, fcd.xml.
They are written beside --out (DIR.partial-PID) and moved into place at the end. Ctrl-C or
SIGTERM stops the run after the step under way; what was gathered is written, summary.json
saying "complete": false and why.
"""

BATCH_EPILOG = """\
The sweep file (TOML):

  name = "demo"                      # optional; default: the file's name
  base = "paper.toml"                # the base scenario, relative to the sweep file
  controllers = ["swarm", "cacc"]    # optional; default: swarm and cacc
  seeds = [42, 43]                   # optional; default: the base scenario's seed

  [fixed]                            # applied to every run
  "simulation.duration_s" = 60.0

  [grid]                             # every combination of these values
  "scene.upstream_gap_m" = [20.0, 25.0, 30.0]
  "cav.count" = [4, 6]

  [[cases]]                          # and/or cases, each crossed with the grid
  "scene.hv.hv_target.speed_mps" = 15.0
  "scene.hv.hv_target.desired_speed_mps" = 15.0

Runs = cases x grid points x seeds x controllers. A parameter is a dotted key of the scenario
file: section.key (cav.count), a key of a nested table (planner.weights.w_tar), or a key of
one item of a list of tables picked by its id (scene.hv.hv_target.speed_mps). Every run is
checked before any starts.

Your own SUMO configuration instead of a base scenario:

  sumocfg = "road.sumocfg"           # relative to the sweep file
  cav_type = "cav"                   # the CAVs' vType (as run --cav-type)
  cav_share_of = "distribution"      # or "passenger" (of all passenger vehicles)
  [grid]
  cav_share = [0.1, 0.3, 0.6]        # the CAV share, 0 to 1
  scale = [1.0, 1.5]                 # SUMO's --scale (demand); seeds are SUMO's --seed

--out DIR holds sweep.json, results.parquet (one row per run: parameters, run_id, status,
error and every summary field, flattened with dots), upstream.parquet, runs/<run_id>/ (each
run's outputs) and impact/ (tables and plots). Stop it at any moment and run the same command
again to resume: finished runs are skipped. Exit status 1 when any run failed.
"""


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as bad input (exit 2) in one line."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> None:  # type: ignore[override]
        raise ConfigError(f"{self.prog}: {message}{self._nearest(message)}")

    def _nearest(self, message: str) -> str:
        """'; did you mean ...?' for a mistyped choice or option, else ''."""
        choice = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if choice:
            wanted, known = choice[1], re.findall(r"'([^']*)'", choice[2])
        else:
            given = re.search(r"unrecognized arguments: (.*)", message)
            words = [w for w in (given[1].split() if given else []) if w.startswith("--")]
            if not words:
                return ""
            wanted, known = words[0].split("=")[0], _option_strings(self)
        near = did_you_mean(wanted, known)
        return f"; did you mean '{near}'?" if near and near != wanted else ""


def _option_strings(parser: argparse.ArgumentParser) -> list[str]:
    """Every long option of ``parser`` and of its commands."""
    found = []
    for action in parser._actions:
        found += [o for o in action.option_strings if o.startswith("--")]
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found += _option_strings(sub)
    return list(dict.fromkeys(found))


def _int_at_least(minimum: int, maximum: int | None = None):
    """An argparse type: an integer in [minimum, maximum]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum or (maximum is not None and value > maximum):
            upper = f" and <= {maximum}" if maximum is not None else ""
            raise argparse.ArgumentTypeError(f"must be >= {minimum}{upper}, got {value}")
        return value

    return parse


def _float_in(low: float, high: float | None = None, *, low_open: bool = False):
    """An argparse type: a finite number in [low, high] ((low, high] with ``low_open``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        too_low = value <= low if low_open else value < low
        if not math.isfinite(value) or too_low or (high is not None and value > high):
            lower = f"> {low:g}" if low_open else f">= {low:g}"
            upper = f" and <= {high:g}" if high is not None else ""
            raise argparse.ArgumentTypeError(f"must be {lower}{upper}, got {text}")
        return value

    return parse


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="sumo-swarm", description=_wrap(DESCRIPTION), epilog=_wrap(EXIT_STATUS))
    parser.add_argument("--version", action="version", version=f"sumo-swarm {__version__}")
    parser.add_argument(
        "-v", "--verbose", action="store_true", help="log progress details (default: off)"
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser(
        "run",
        help="one headless run of a scenario file or of your own SUMO configuration",
        description=_wrap(
            "One headless run of a scenario file (or, with --sumocfg, of your own SUMO "
            "configuration) under one controller."
        ),
        epilog=RUN_EPILOG,
    )
    run.add_argument(
        "scenario",
        nargs="?",
        type=Path,
        metavar="SCENARIO.toml",
        help="the scenario file (see below); omit it with --sumocfg",
    )
    run.add_argument(
        "--sumocfg",
        type=Path,
        metavar="FILE",
        help="run this SUMO configuration as it is (default: none, SCENARIO.toml is run)",
    )
    run.add_argument(
        "--cav-type",
        metavar="TYPE",
        help="with --sumocfg, required: the vType whose vehicles form the swarm",
    )
    run.add_argument(
        "--config",
        type=Path,
        metavar="SWARM.toml",
        help="with --sumocfg: the swarm's settings, a scenario file whose [cav], [swarm], "
        "[planner], ... sections apply (default: the built-in settings, cruising at the CAV "
        "vType's maxSpeed)",
    )
    run.add_argument(
        "--scale",
        type=_float_in(0.0, low_open=True),
        metavar="X",
        help="with --sumocfg: SUMO's --scale, the demand factor (default: the configuration's)",
    )
    run.add_argument(
        "--cav-share",
        type=_float_in(0.0, 1.0),
        metavar="P",
        help="with --sumocfg: the share of CAVs, 0 to 1, of --cav-share-of, drawn by SUMO "
        "with the seed (default: the configuration's own)",
    )
    run.add_argument(
        "--cav-share-of",
        choices=("distribution", "passenger"),
        default="distribution",
        help="what --cav-share is a share of: the vTypeDistributions holding --cav-type, or all "
        "passenger vehicles (default: %(default)s)",
    )
    run.add_argument(
        "--controller", default="swarm", choices=CONTROLLERS, metavar="NAME", help=CONTROLLER_HELP
    )
    run.add_argument(
        "--seed",
        type=_int_at_least(0, SEED_MAX),
        metavar="N",
        help="SUMO's random seed, 0 or more (default: the scenario's [simulation] seed; with "
        "--sumocfg, the configuration's, else SUMO's default 23423)",
    )
    run.add_argument(
        "--out",
        type=Path,
        default=Path("out"),
        metavar="DIR",
        help="output folder: new or empty, or with --force one holding an earlier run "
        "(default: %(default)s)",
    )
    run.add_argument(
        "--force",
        action="store_true",
        help="replace the earlier run --out holds (default: off, such a folder is refused)",
    )
    run.add_argument(
        "--fcd", action="store_true", help="also write SUMO's fcd-output, fcd.xml (default: off)"
    )
    run.add_argument(
        "--gui",
        action="store_true",
        help="watch the run in sumo-gui (through traci, slower; default: off)",
    )

    rep = sub.add_parser(
        "reproduce",
        help="the paper's evaluation (Section IV): all controllers, report and figures",
        description=_wrap(
            "The paper's evaluation (Section IV): the paper's scenario under every controller, "
            "report.md and report.json with the paper's value beside each measure, and the "
            "figures (PNG)."
        ),
    )
    rep.add_argument(
        "--out",
        type=Path,
        default=Path("reproduce"),
        metavar="DIR",
        help="output folder (default: %(default)s)",
    )
    rep.add_argument(
        "--scenario",
        type=Path,
        default=None,
        metavar="SCENARIO.toml",
        help="the scenario to evaluate (default: the paper's; 'sumo-swarm run --help' says "
        "where it is installed)",
    )

    bat = sub.add_parser(
        "batch",
        help="a resumable sweep of runs, on this machine or on a Ray cluster",
        description=_wrap(
            "Run every run of a sweep file, one SUMO process per run, and keep the results in "
            "--out. Resumable: run the same command again after a stop."
        ),
        epilog=BATCH_EPILOG,
    )
    bat.add_argument("sweep", type=Path, metavar="SWEEP.toml", help="the sweep file (see below)")
    bat.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="DIR",
        help="required: the batch folder (resumed if it holds the same sweep)",
    )
    bat.add_argument(
        "--workers",
        type=_int_at_least(1),
        default=None,
        metavar="N",
        help="runs at a time (default: one per CPU; with --ray, the cluster's CPUs)",
    )
    bat.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run on Ray: 'auto' or a cluster address; needs pip install 'sumo-swarm[cluster]' "
        "(default: local processes)",
    )
    bat.add_argument(
        "--retry-failed",
        action="store_true",
        help="run the runs recorded as failed again (default: off, they count as finished)",
    )

    imp = sub.add_parser(
        "impact",
        help="traffic-impact tables and plots of a batch folder",
        description=_wrap(
            "Traffic-impact tables (CSV and markdown) and plots across a finished sweep, "
            "written to DIR/impact/ (batch writes them too, at its end)."
        ),
    )
    imp.add_argument("dir", type=Path, metavar="DIR", help="the --out folder of a batch")
    rpl = sub.add_parser(
        "replay",
        help="an animation (MP4 or GIF) of a finished run",
        description=_wrap(
            "An animation of a finished run from its outputs: the network's lanes, the vehicles "
            "to scale coloured by role (target, blockers, other CAVs, HVs), the plan's cells, "
            "time and speeds."
        ),
    )
    rpl.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="the --out folder of a run")
    rpl.add_argument(
        "--out",
        type=Path,
        metavar="FILE",
        help="FILE.mp4 or FILE.gif (default: RUN_DIR/replay.mp4)",
    )
    rpl.add_argument(
        "--follow", metavar="VEHICLE", help="keep this vehicle in view (default: the swarm)"
    )
    rpl.add_argument(
        "--from",
        dest="t_from",
        type=float,
        metavar="S",
        help="start [s] (default: when the first CAV appears)",
    )
    rpl.add_argument(
        "--to", dest="t_to", type=float, metavar="S", help="end [s] (default: the end of the run)"
    )
    rpl.add_argument("--fps", type=float, default=10.0, help="frames per second (default: 10)")
    return parser


def _cmd_run(args: argparse.Namespace) -> int:
    from sumo_swarm.config import load_scenario
    from sumo_swarm.sim.bridge import require_display
    from sumo_swarm.sim.runner import run_scenario

    if args.gui:
        require_display()  # before anything is read or written

    if args.sumocfg is not None:
        if args.scenario is not None:
            raise ConfigError("run: give a scenario file or --sumocfg, not both")
        if not args.cav_type:
            raise ConfigError("run: --sumocfg needs --cav-type TYPE (the swarm's vType)")
        from sumo_swarm.sim.runner import run_sumocfg

        summary = run_sumocfg(
            args.sumocfg,
            args.cav_type,
            args.controller,
            args.out,
            config=args.config,
            seed=args.seed,
            fcd=args.fcd,
            gui=args.gui,
            notify=lambda line: print(line, file=sys.stderr),
            force=args.force,
            scale=args.scale,
            cav_share=args.cav_share,
            cav_share_of=args.cav_share_of,
            require_cavs=args.cav_share is None,  # a share may give no CAV (0, or by chance)
        )
    else:
        # An option of --sumocfg given without it would be dropped silently: the run the user
        # gets is not the one asked for.
        given = {"--scale": args.scale, "--cav-share": args.cav_share,
                 "--cav-type": args.cav_type, "--config": args.config}  # fmt: skip
        stray = [option for option, value in given.items() if value is not None]
        if stray:
            raise ConfigError(f"run: {' and '.join(stray)} go with --sumocfg")
        if args.scenario is None:
            raise ConfigError("run: give a scenario file (or --sumocfg FILE --cav-type TYPE)")
        scenario = load_scenario(args.scenario)
        summary = run_scenario(
            scenario,
            args.controller,
            args.out,
            seed=args.seed,
            fcd=args.fcd,
            gui=args.gui,
            force=args.force,
        )
    from sumo_swarm.sim.summary import manoeuvre_line

    cav = summary["cav"]
    print(
        f"{summary['scenario']}/{summary['controller']}: CAV mean speed "
        f"{_num(cav['mean_speed_mps'])} m/s, min gap {_num(cav['gap_min_m'])} m, "
        f"{manoeuvre_line(summary)}, "
        f"collisions={summary['safety']['collisions']}, "
        f"hard brakes={summary['safety']['hard_brakes']}, "
        f"wall {summary['timing']['wall_s']:.1f} s -> {args.out}"
    )
    # The controller failed and handed its CAVs back to SUMO (one warning said so): the outputs
    # are whole, but not a run of this controller to its end.
    return EXIT_FAILURE if summary.get("stood_down") else EXIT_OK


def _num(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from sumo_swarm.study.reproduce import reproduce

    reproduce(args.out, scenario_path=args.scenario)
    print(f"report: {args.out / 'report.md'} (report.json, figures and runs/ in {args.out})")
    return EXIT_OK


def _cmd_batch(args: argparse.Namespace) -> int:
    from sumo_swarm.study.batch import run_batch
    from sumo_swarm.userfiles import check_sumo_path

    check_sumo_path(args.out.resolve(), "batch folder")  # every run's SUMO writes there

    report = run_batch(
        args.sweep, args.out, workers=args.workers, ray=args.ray, retry_failed=args.retry_failed
    )
    print(report.table())
    print(f"impact tables and plots: {args.out / 'impact' / 'impact.md'}")
    return EXIT_FAILURE if report.failed else EXIT_OK


def _cmd_impact(args: argparse.Namespace) -> int:
    from sumo_swarm.study.impact import impact

    print(impact(args.dir))
    print(f"impact tables and plots: {args.dir / 'impact'}")
    return EXIT_OK


class _Signalled(RunInterrupted):
    """A command stopped by SIGTERM or SIGHUP where it was (its message says only that)."""


def _raise_interrupted(signum: int, frame) -> None:
    """SIGTERM (and SIGHUP) as Ctrl-C: the commands' cleanup runs and one line says so."""
    name = signal.Signals(signum).name
    raise _Signalled(f"interrupted by {name}", 128 + signum)


def _interrupted_line(exc: KeyboardInterrupt, command: str | None, out: Path | None) -> str:
    """One line for an interrupted command: what it kept and how to go on."""
    if isinstance(exc, RunInterrupted) and not isinstance(exc, _Signalled):
        return " ".join(exc.message.split())  # a run's own account of what it kept
    text = exc.message if isinstance(exc, RunInterrupted) else "interrupted by SIGINT"
    if command == "batch" and out is not None:
        text += f": finished runs are kept in {out}; run the same command again to resume"
    elif command == "reproduce" and out is not None:
        text += f': the report so far is in {out} (report.json: "complete": false)'
    elif command == "run" and out is not None:  # before the run began
        text += f": nothing written to {out}"
    return " ".join(text.split())


def main(argv: list[str] | None = None) -> int:
    args = None
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for name in ("SIGTERM", "SIGHUP"):
            sig = getattr(signal, name, None)
            if sig is not None and signal.getsignal(sig) is not signal.SIG_IGN:  # nohup: ignored
                previous[sig] = signal.signal(sig, _raise_interrupted)
    try:
        args = build_parser().parse_args(argv)
        logging.basicConfig(
            level=logging.INFO if args.verbose else logging.WARNING,
            format="%(levelname)s %(name)s: %(message)s",
        )
        if args.command == "run":
            return _cmd_run(args)
        if args.command == "reproduce":
            return _cmd_reproduce(args)
        if args.command == "batch":
            return _cmd_batch(args)
        if args.command == "impact":
            return _cmd_impact(args)
        if args.command == "replay":
            from sumo_swarm.study.replay import replay_command

            return replay_command(args)
        raise ConfigError(f"unknown command {args.command}")
    except ConfigError as exc:
        print(f"sumo-swarm: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SimulationError as exc:
        print(f"sumo-swarm: simulation failed: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt as exc:
        command, out = getattr(args, "command", None), getattr(args, "out", None)
        print(f"sumo-swarm: {_interrupted_line(exc, command, out)}", file=sys.stderr)
        return exc.exit_status if isinstance(exc, RunInterrupted) else 130
    except Exception as exc:  # one line, not a traceback; --verbose logs the traceback
        logging.getLogger("sumo_swarm").debug("unexpected error", exc_info=True)
        print(f"sumo-swarm: unexpected error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


if __name__ == "__main__":
    sys.exit(main())
