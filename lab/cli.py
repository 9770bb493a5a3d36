"""The lab's command line: study NAME ... [--group TARGET] and readme (python -m lab, or
python -m driver and the fdcontact command in a checkout, which hand these two here)."""

import argparse
import sys

from driver import progress
from driver.cli import guarded

from .studies import REGISTRY, groups


def cmd_study(args):
    from driver import sweep

    from .studies import study

    unknown = [n for n in args.names if n not in REGISTRY]
    if unknown or not (args.names or args.group):
        print(f"error: study: unknown study {unknown[0]!r} ({args.prog} study --help lists them)" if unknown
              else "error: study: name a study or a --group", file=sys.stderr)
        return 2
    names = [*(groups()[args.group] if args.group else []), *args.names]
    sweep.configure(workers=args.workers, scheduler=args.scheduler)
    for name in names:
        with progress.study_bar(name):
            study(name)()
    return 0


def cmd_readme(args):
    from .readme import update

    update()
    return 0


def build_parser(prog):
    parser = argparse.ArgumentParser(prog=prog, description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    study = sub.add_parser("study", help="run a study: tables in results/, plots in plots/")
    study.add_argument("names", nargs="*", metavar="NAME", help=f"a study: {', '.join(sorted(REGISTRY))}")
    study.add_argument("--group", choices=sorted(groups()),
                       help="the studies of a make target, in their order (lab/studies/__init__.py)")
    study.add_argument("--workers", type=int, help="Dask worker processes for the studies that run their "
                       "points as a sweep (fd2d-convergence, fd2d-gamma0; default: the number of cores)")
    study.add_argument("--scheduler", help="send those points to an existing Dask scheduler tcp://HOST:PORT")
    study.set_defaults(func=cmd_study, prog=prog)
    readme = sub.add_parser("readme", help="refill the generated tables of README.md and docs/*.md from "
                                           "results/*.csv and write docs/scenes.md and the flag rules from the "
                                           "schemas")
    readme.set_defaults(func=cmd_readme)
    return parser


def main(argv=None, prog="python -m lab"):
    args = build_parser(prog).parse_args(argv)
    return guarded(args.func, args)
