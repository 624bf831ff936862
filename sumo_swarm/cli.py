"""The ``sumo-swarm`` command.

Exit status: 0 success, 2 bad input (one line on stderr naming the problem, no traceback),
1 anything else.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from sumo_swarm import __version__
from sumo_swarm.controllers import CONTROLLERS
from sumo_swarm.errors import ConfigError, SimulationError

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as bad input (exit 2) in one line."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise ConfigError(f"{self.prog}: {message}")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="sumo-swarm", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"sumo-swarm {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser("run", help="one headless run of a scenario file")
    run.add_argument("scenario", nargs="?", type=Path, help="scenario TOML file")
    run.add_argument("--sumocfg", type=Path, help="a SUMO configuration to run as it is")
    run.add_argument("--cav-type", help="with --sumocfg: the vType whose vehicles form the swarm")
    run.add_argument("--config", type=Path, help="with --sumocfg: swarm settings (TOML)")
    run.add_argument("--controller", default="swarm", choices=CONTROLLERS)
    run.add_argument("--seed", type=int, default=None)
    run.add_argument("--out", type=Path, default=Path("out"))
    run.add_argument("--fcd", action="store_true", help="also write SUMO's fcd-output (fcd.xml)")
    run.add_argument("--gui", action="store_true", help="watch the run in sumo-gui (traci)")

    rep = sub.add_parser(
        "reproduce", help="the paper's evaluation (Section IV), report and figures"
    )
    rep.add_argument("--out", type=Path, default=Path("reproduce"))
    rep.add_argument("--scenario", type=Path, default=None, help="default: the paper scenario")

    bat = sub.add_parser("batch", help="a resumable sweep of runs (docs/batch.md)")
    bat.add_argument("sweep", type=Path, help="sweep TOML file")
    bat.add_argument("--out", type=Path, required=True, help="batch folder (resumed if it exists)")
    bat.add_argument("--workers", type=int, default=None, help="runs at a time (default: CPUs)")
    bat.add_argument("--ray", metavar="ADDRESS", help="run on Ray: 'auto' or a cluster address")
    bat.add_argument("--retry-failed", action="store_true", help="run failed runs again")
    imp = sub.add_parser("impact", help="traffic-impact tables and plots of a batch folder")
    imp.add_argument("dir", type=Path, help="the --out folder of a batch")
    rpl = sub.add_parser("replay", help="an animation (MP4 or GIF) of a finished run")
    rpl.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="the --out folder of a run")
    rpl.add_argument("--out", type=Path, help="FILE.mp4 or FILE.gif (default: RUN_DIR/replay.mp4)")
    rpl.add_argument(
        "--follow", metavar="VEHICLE", help="keep this vehicle in view (default: swarm)"
    )
    rpl.add_argument(
        "--from", dest="t_from", type=float, metavar="S", help="start [s] (default: 0)"
    )
    rpl.add_argument(
        "--to", dest="t_to", type=float, metavar="S", help="end [s] (default: the end)"
    )
    rpl.add_argument("--fps", type=float, default=10.0, help="frames per second (default: 10)")
    return parser


def _cmd_run(args: argparse.Namespace) -> int:
    from sumo_swarm.config import load_scenario
    from sumo_swarm.runner import run_scenario

    if args.sumocfg is not None:
        if args.scenario is not None:
            raise ConfigError("run: give a scenario file or --sumocfg, not both")
        if not args.cav_type:
            raise ConfigError("run: --sumocfg needs --cav-type TYPE (the swarm's vType)")
        from sumo_swarm.runner import run_sumocfg

        summary = run_sumocfg(
            args.sumocfg, args.cav_type, args.controller, args.out, config=args.config,
            seed=args.seed, fcd=args.fcd, gui=args.gui,
            notify=lambda line: print(line, file=sys.stderr),
        )  # fmt: skip
    else:
        if args.scenario is None:
            raise ConfigError("run: give a scenario file (or --sumocfg FILE --cav-type TYPE)")
        scenario = load_scenario(args.scenario)
        summary = run_scenario(
            scenario, args.controller, args.out, seed=args.seed, fcd=args.fcd, gui=args.gui
        )
    cav = summary["cav"]
    ot = summary["overtake"]
    print(
        f"{summary['scenario']}/{summary['controller']}: CAV mean speed "
        f"{_num(cav['mean_speed_mps'])} m/s, min gap {_num(cav['gap_min_m'])} m, "
        f"overtake completed={ot['completed']} regrouped={ot['regrouped']}, "
        f"collisions={summary['safety']['collisions']}, "
        f"hard brakes={summary['safety']['hard_brakes']}, "
        f"wall {summary['timing']['wall_s']:.1f} s -> {args.out}"
    )
    return EXIT_OK


def _num(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from sumo_swarm.reproduce import reproduce

    reproduce(args.out, scenario_path=args.scenario)
    return EXIT_OK


def _cmd_batch(args: argparse.Namespace) -> int:
    from sumo_swarm.batch import run_batch

    report = run_batch(
        args.sweep, args.out, workers=args.workers, ray=args.ray, retry_failed=args.retry_failed
    )
    print(report.table())
    print(f"impact tables and plots: {args.out / 'impact' / 'impact.md'}")
    return EXIT_FAILURE if report.failed else EXIT_OK


def _cmd_impact(args: argparse.Namespace) -> int:
    from sumo_swarm.impact import impact

    print(impact(args.dir))
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
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
            from sumo_swarm.replay import replay_command

            return replay_command(args)
        raise ConfigError(f"unknown command {args.command}")
    except ConfigError as exc:
        print(f"sumo-swarm: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SimulationError as exc:
        print(f"sumo-swarm: simulation failed: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("sumo-swarm: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one line, not a traceback; --verbose logs the traceback
        logging.getLogger("sumo_swarm").debug("unexpected error", exc_info=True)
        print(f"sumo-swarm: unexpected error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
