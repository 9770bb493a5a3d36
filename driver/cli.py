"""Command line: python -m driver run SCENE [--set key=value ...], scene-module, sweep, plot;
study and readme in a checkout (the lab's)."""

import argparse
import importlib.util
import os
import re
import signal
import sys
from pathlib import Path

from . import progress
from .errors import DriverError
from .paths import IN_CHECKOUT, REPO
from .runner import Interrupted

# Commands whose parsers need nothing from driver.sweep: for these the sweep
# commands' parsers (and with them driver.sweep) are not built.
OWN_COMMANDS = ("run", "scene-module", "plot")

# The lab's commands: the studies and the docs' generated parts are not in the package
# but beside it in a checkout (lab/, `python -m lab`), which imports the package by its
# checkout name, driver. An installed package has no lab: these commands say so (exit 2).
LAB_COMMANDS = {"study": "run a study: tables in results/, plots in plots/ (a checkout's lab/)",
                "readme": "refill the generated tables of README.md and docs/*.md from results/*.csv and "
                          "write docs/scenes.md and the flag rules from the schemas (a checkout's lab/)"}
LAB = REPO / "lab"


def cmd_run(args):
    from .runner import run_scene
    from .scene import load_scene

    scene, module = load_scene(args.scene, args.set)
    steps = scene.get("adapt", {}).get("steps", 0)
    # FreeFEM prints one "step K" line per solve of an adaptive run: a bar over them.
    bar = None if args.verbose or not steps else progress.bar(total=steps + 1, desc=scene["scene"]["name"],
                                                              unit="step")
    try:
        results, folder, wall = run_scene(scene, module, out_dir=args.out, script=args.script,
                                          echo=progress_echo(args.verbose, bar), replace=args.replace)
    finally:
        if bar is not None:
            bar.close()
    print(format_summary(scene, module, results, folder, wall))
    return 0


def progress_echo(verbose, bar=None):
    """All of FreeFEM's output with -v; otherwise only adaptation steps (long runs),
    which also move the bar."""
    def echo(line):
        if verbose:
            print(line, flush=True)
        elif line.startswith("step "):
            progress.write(f"  {line}")
            if bar is not None:
                bar.update(1)
    return echo


def format_summary(scene, module, results, folder, wall):
    meth = scene["method"]
    newton = results["newton"]
    timings = results.get("timings_cpu_s", {})
    lines = [
        f"scene {scene['scene']['name']} ({scene['scene']['script']}, P{meth['degree']}, "
        f"theta={meth['theta']:g}, gamma0={meth['gamma0']:.4g})",
        *(module.summary_head(results) if hasattr(module, "summary_head") else []),
        f"mesh: {results['elements']} elements, h_max {results['h_max']:.4g}, {results['dofs']} DOFs",
        f"newton: {newton['iterations']} iterations, final residual {newton['residual'][-1]:.2e}",
    ]
    lines += module.summary_lines(results)
    phases = ", ".join(f"{k} {v:.2f}" for k, v in timings.items())
    lines.append(f"time: {wall:.2f} s wall (FreeFEM cpu s: {phases})")
    outputs = ", ".join(results.get("outputs", {}).values())
    lines.append(f"outputs: {folder}/results.json" + (f" ({outputs})" if outputs else ""))
    return "\n".join(lines)


def cmd_scene_module(args):
    from .scene import load_scene

    scene, module = load_scene(args.scene, args.set)
    if not hasattr(module, "scene_module"):
        print(f"error: {scene['scene']['script']} takes no scene module", file=sys.stderr)
        return 2
    sys.stdout.write(module.scene_module(scene))
    return 0


def cmd_plot(args):
    from .plot import plot_run

    for path in plot_run(args.run, plane=args.plane, scale=args.scale):
        print(path)
    return 0


def lab_command(argv):
    """study and readme: run by the checkout's lab. Under the package's checkout name
    (python -m driver) in this process; under its installed name (the fdcontact command) the
    lab, which imports it as driver, replaces this process (python -m lab), so that each
    module is loaded once."""
    command = first_command(argv)
    if not (IN_CHECKOUT and (LAB / "studies" / "__init__.py").is_file()):
        print(f"error: {command}: the studies and the docs' tables are a checkout's (lab/ beside driver/, "
              f"python -m lab); this installed package has none", file=sys.stderr)
        return 2
    if __package__ != "driver":
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
        try:
            os.execve(sys.executable, [sys.executable, "-P", "-m", "lab", *argv], env)
        except OSError as exc:
            print(f"error: {command}: cannot start {sys.executable} -m lab: {exc.strerror or exc}", file=sys.stderr)
            return 4
    found = importlib.util.find_spec("lab")
    if found is None or Path(found.origin).resolve() != (LAB / "__init__.py").resolve():
        print(f"error: {command}: the module lab found first ({found.origin if found else 'none'}) is not the "
              f"checkout's {LAB}", file=sys.stderr)
        return 2
    from lab.cli import main as lab_main

    return lab_main(argv, prog="python -m driver")


def first_command(argv):
    """The command word of a command line (its first word not starting with -)."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(argv=None):
    """The command line; the sweep commands only when argv may name them (or asks for help)."""
    parser = argparse.ArgumentParser(prog="python -m driver", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="validate a scene, run FreeFEM, print a summary")
    run.add_argument("scene", help="scene file (TOML), e.g. cases/square_slip_separation.toml")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="override a scene value by dotted key, e.g. mesh.nx=80 (repeatable)")
    run.add_argument("--out", help="run folder (default runs/NAME-TIME-HASH); must be new, empty, "
                     "or a previous run with --replace")
    run.add_argument("--replace", action="store_true",
                     help="replace the previous run in --out once the new one has converged")
    run.add_argument("--script", help="use this .edp instead of the scene's script (development)")
    run.add_argument("-v", "--verbose", action="store_true", help="echo FreeFEM's output")
    run.set_defaults(func=cmd_run)
    module = sub.add_parser("scene-module", help="print the FreeFEM scene module of a scene "
                                                 "(docs/scene-modules.md) without running it")
    module.add_argument("scene", help="scene file (TOML)")
    module.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="as for run")
    module.set_defaults(func=cmd_scene_module)
    for name, text in LAB_COMMANDS.items():     # listed for --help; main hands them to the lab
        sub.add_parser(name, help=text, add_help=False)
    if first_command(sys.argv[1:] if argv is None else argv) not in OWN_COMMANDS:
        from .sweep import add_parser as add_sweep_parsers

        add_sweep_parsers(sub)
    plot = sub.add_parser("plot", help="figures of a run folder (PNG files written into it, docs/outputs.md)")
    plot.add_argument("run", help="run folder, e.g. runs/NAME-TIME-HASH")
    plot.add_argument("--plane", help="3D: the cut plane AXIS=VALUE, e.g. y=0 (default: y through the contact)")
    plot.add_argument("--scale", type=float, default=1.0, help="displacement magnification (default 1)")
    plot.set_defaults(func=cmd_plot)
    return parser


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if first_command(argv) in LAB_COMMANDS:
        return lab_command(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if hasattr(args, "set"):
        args.set = [item for chunk in args.set for item in split_overrides(chunk)]
    return guarded(args.func, args)


def guarded(func, args):
    """func(args) as a command: a DriverError is one line and its exit code, SIGINT and
    SIGTERM end it cleanly (128 + the signal), an OSError is exit 4."""
    previous = {sig: signal.signal(sig, raise_interrupted) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        return func(args)
    except DriverError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    except (Interrupted, KeyboardInterrupt) as exc:
        signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
        detail = f" ({exc.detail})" if isinstance(exc, Interrupted) and exc.detail else ""
        print(f"error: interrupted by {signal.Signals(signum).name}{detail}", file=sys.stderr)
        return 128 + signum
    except OSError as exc:
        print(f"error: {exc.strerror or exc}" + (f": {exc.filename}" if exc.filename else ""), file=sys.stderr)
        return 4
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


KEY_START = re.compile(r"[A-Za-z_][\w.]*=")


def split_overrides(chunk):
    """"--set 'a=1 b=[0, 2]'" (as make passes SET) means two overrides: split at white space
    that starts a new KEY=, not inside a quoted string or brackets ('d="load b=5 kN"' is one)."""
    items, current, quote, depth = [], [], None, 0
    i = 0
    text = chunk.strip()
    while i < len(text):
        char = text[i]
        if quote:
            if char == "\\" and quote == '"' and i + 1 < len(text):
                current.append(text[i:i + 2])
                i += 2
                continue
            quote = None if char == quote else quote
        elif char in "\"'":
            quote = char
        elif char in "[{":
            depth += 1
        elif char in "]}":
            depth -= 1
        elif char.isspace() and depth <= 0:
            following = len(text) - len(text[i:].lstrip())     # the next non-blank character
            if KEY_START.match(text, following):
                items.append("".join(current))
                current = []
                i = following
                continue
        current.append(char)
        i += 1
    items.append("".join(current))
    return [item.strip() for item in items if item.strip()]


def raise_interrupted(signum, frame):
    """SIGINT and SIGTERM end a run cleanly: FreeFEM stopped, its folder marked failed."""
    raise Interrupted(signum)
