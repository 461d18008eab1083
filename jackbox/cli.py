"""The ``jackbox`` command: run scenes and see them, compare impact laws, regenerate
kernels, list scenes.

Mistakes that are the user's (a bad scene, a missing file, a bad ``--set`` or
option value) print one ``jackbox: error: ...`` line and exit with status 2;
nothing is written. A run that goes wrong (the state turns non-finite) exits
with status 1; a study with members that did not complete, 3 (see EXIT_CODES). Pictures are made by :mod:`jackbox.plots` (Matplotlib) and
:mod:`jackbox.animate` (Plotly), imported only when a command draws.
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

from . import __version__
from .errors import CacheWarning, JackboxError, RunStoppedError, SolverWarning
from .fileio import check_writable
from .process import end

EPILOG = """\
examples:
  jackbox run                          run the built-in scene 'shaken': trajectory, time series, animation
  jackbox run drop --set restitution=0.6 --t-end 3
  jackbox run my_scene.toml --out results/ --no-plots
  jackbox compare drop --restitution 1.0 0.6      elastic vs inelastic, one figure
  jackbox animate runs/drop/trajectory.npz --speed 0.25
  jackbox plot runs/drop/trajectory.npz          the time series of a saved run
  jackbox ensemble shaken --n 100000 --perturb theta_jack=1e-6     10^5 members on every core
  jackbox ensemble drop --n 400 --sweep restitution=0.5:1.0 --dask local
  jackbox chaos shaken --n 2000 --t-end 10       twin trajectories: FTLE estimate and its spread
  jackbox bench                        step throughput, skip gains, C ceiling, ensemble scaling
  jackbox build                        regenerate generated/ for the built-in scenes
  jackbox scenes                       list the built-in scenes
  jackbox cache                        where compiled code is cached, its size; jackbox cache clear

exit status:
  0    done
  1    a run stopped: its state became non-finite, or its contacts stalled
  2    a mistake in the command, the scene or an option (one "jackbox: error:" line; nothing written)
  3    ensemble or chaos: some members did not complete (counted in the summary; their
       results are NaN in the .npz)
  130  interrupted (Ctrl-C); 143 terminated (SIGTERM): files being written are removed
"""
#: a study with members that did not complete (their results are NaN)
EXIT_INCOMPLETE = 3


class _Parser(argparse.ArgumentParser):
    """argparse, with its usage errors on one ``jackbox: error:`` line like every other mistake."""

    def error(self, message: str):
        self.exit(2, f"jackbox: error: {message} (see {self.prog} --help)\n")


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    previous = _on_sigterm(_terminate)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return args.func(args)
    except JackboxError as exc:
        print(f"jackbox: error: {exc}", file=sys.stderr)
        return 1 if isinstance(exc, RunStoppedError) else 2
    except OSError as exc:
        where = f" {exc.filename}" if exc.filename else ""
        print(f"jackbox: error:{where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jackbox: interrupted", file=sys.stderr)
        return 130
    except _Terminated:
        print("jackbox: terminated", file=sys.stderr)
        return 143
    finally:
        _on_sigterm(previous)


def console() -> None:
    """The ``jackbox`` program: :func:`main`, then the process ends at once (:func:`jackbox.process.end`).

    Python's cyclic collector is off in the program (garbage is freed by its
    reference counts; a reference cycle lives until the process ends):
    importing NumPy and Numba and loading the kernels made it collect again
    and again, 30-50 ms of a 0.5 s warm start (``import jackbox`` loads
    neither, so this comes first). A study on Dask, whose client lives long
    and makes cycles, turns it back on (:func:`_study_kwargs`).
    """
    gc.disable()
    end(main())


class _Terminated(BaseException):
    """SIGTERM, raised where the program is, so that files being written are removed."""


def _terminate(signum, frame):
    raise _Terminated


def _on_sigterm(handler):
    """Install a SIGTERM handler (main thread only); returns the one it replaced."""
    if handler is None or threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, handler)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """jackbox's own warnings as one ``jackbox: warning: ...`` line; others as Python prints them."""
    if issubclass(category, (CacheWarning, SolverWarning)):
        print(f"jackbox: warning: {message}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), end="", file=sys.stderr)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="jackbox", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG,
        description="Simulate a jack bouncing in a box: scenes are compiled to Numba kernels.")
    parser.add_argument("--version", action="version", version=f"jackbox {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    from .api import METHODS

    run = sub.add_parser("run", help="simulate a scene, write its trajectory and pictures",
                         formatter_class=argparse.RawDescriptionHelpFormatter,
                         description="Simulate a scene (default: shaken), print a summary and write, in DIR:\n"
                                     "  trajectory.npz   the trajectory (its keys: docs/scenes.md)\n"
                                     "  timeseries.png   positions, angles, energy, smallest gap, impulses\n"
                                     "  animation.html   the motion, offline, Play/Pause and a time slider\n"
                                     "  plotly.min.js    the library the page loads (written once, kept)\n"
                                     "(--no-plots writes the trajectory only).")
    run.add_argument("scene", nargs="?", default="shaken",
                     help="built-in scene name or path to a .toml scene file (default: shaken)")
    _simulation_options(run, METHODS)
    run.add_argument("--record-every", type=int, default=1, metavar="K",
                     help="keep every K-th step in the output (default: 1)")
    run.add_argument("--out", type=_out_path, metavar="DIR",
                     help="output folder (default: runs/<scene name>)")
    run.add_argument("--no-plots", action="store_true",
                     help="write the trajectory only: no timeseries.png, no animation.html")
    run.add_argument("--plotlyjs", choices=("beside", "inline"), default="beside",
                     help="beside: a small page that loads plotly.min.js from its folder, where it is "
                          "written once and kept for later runs (default); inline: one self-contained "
                          "page of about 5 MB")
    run.add_argument("--quiet", "-q", action="store_true", help="no progress bar or summary")
    run.set_defaults(func=cmd_run)

    compare = sub.add_parser(
        "compare", help="run a scene under several restitutions and compare them in one figure",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run one scene under two or more impact laws, from the same start with the same dt,\n"
                    "print a summary (energy lost, impulses, time to settle) and write DIR/comparison.png:\n"
                    "energy over time, the jack's height at each impulse, impulse counts.\n\n"
                    "Each --restitution value E sets both the jack-wall restitution e and the box-ground\n"
                    "restitution e_ground (for a scene without ground_restitution this is what\n"
                    "--set restitution=E does). A run has settled once its energy stays within 1% of the\n"
                    "energy it lost of its final value, for at least the last 10% of the run.")
    compare.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    compare.add_argument("--restitution", "-e", nargs="+", required=True, metavar="E",
                         help="two or more restitutions in [0, 1] (1 elastic, 0 plastic)")
    _simulation_options(compare, METHODS)
    compare.add_argument("--out", type=_out_path, metavar="DIR",
                         help="output folder (default: runs/<scene name>)")
    compare.add_argument("--quiet", "-q", action="store_true", help="no progress bar or summary")
    compare.set_defaults(func=cmd_compare)

    animate = sub.add_parser(
        "animate", help="make the animation of a saved trajectory",
        description="Write an offline HTML animation of a trajectory .npz: the box's inner and outer "
                    "boundary, the jack's shape, the ground, a trail of the jack's centre, impulses "
                    "highlighted; Play/Pause and a time slider. It plays at real time by default.")
    animate.add_argument("file", type=Path, metavar="FILE.npz", help="a trajectory written by jackbox run")
    animate.add_argument("--out", type=_out_path, metavar="PATH.html",
                         help="output page (default: animation.html beside a run's trajectory.npz, "
                              "else FILE with .html)")
    animate.add_argument("--fps", type=_positive, default=25.0,
                         help="frames per second of playback (default: 25)")
    animate.add_argument("--speed", type=_positive, default=1.0,
                         help="simulated seconds per second of playback (default: 1, real time)")
    animate.add_argument("--max-frames", type=_frames, default=1000, metavar="N",
                         help="at most N frames: a longer run plays at a lower frame rate (default: 1000)")
    animate.add_argument("--trail", type=_non_negative, default=1.0, metavar="S",
                         help="seconds of simulated time in the jack centre's trail (default: 1)")
    animate.add_argument("--plotlyjs", choices=("inline", "beside"), default="inline",
                         help="inline: one self-contained page (default); beside: a small page that "
                              "loads plotly.min.js written in its folder")
    animate.add_argument("--quiet", "-q", action="store_true", help="no progress bar or summary")
    animate.set_defaults(func=cmd_animate)

    plot = sub.add_parser("plot", help="draw the time series of a saved trajectory",
                          description="Write the time series PNG of a trajectory .npz (as jackbox run does).")
    plot.add_argument("file", type=Path, metavar="FILE.npz", help="a trajectory written by jackbox run")
    plot.add_argument("--out", type=_out_path, metavar="PATH.png|.pdf|.svg",
                      help="output image, its format from the extension: png, pdf or svg (default: "
                           "timeseries.png beside a run's trajectory.npz, "
                           "else FILE with .png)")
    plot.add_argument("--quiet", "-q", action="store_true", help="no summary")
    plot.set_defaults(func=cmd_plot)

    ens = sub.add_parser(
        "ensemble", help="run N members of a scene in parallel (perturbed starts, parameter sweeps)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run N members of one scene on every core (Numba prange), or on a Dask cluster,\n"
                    "and write DIR/ensemble.npz: per member the final state, impulse count, time of the\n"
                    "first impulse, status, the state at --samples times, and its start and parameters.\n"
                    "Member i depends only on i and --seed: any split of the work gives the same numbers.\n\n"
                    "  --perturb theta_jack=1e-6      start offsets, uniform in [-size, size] (random, or --grid)\n"
                    "  --sweep restitution=0.5:1.0    parameter values spread over the members (two: a grid)")
    ens.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    _study_options(ens)
    ens.add_argument("--samples", type=float, nargs="+", metavar="T",
                     help="increasing times (s) at which to keep every member's state (rounded to whole steps, "
                          "at least one step apart)")
    ens.add_argument("--out", type=_out_path, metavar="DIR", help="output folder (default: runs/<scene name>)")
    _lanes_option(ens, "members")
    ens.set_defaults(func=cmd_ensemble)

    chaos = sub.add_parser(
        "chaos", help="finite-time Lyapunov exponents from renormalised twin trajectories",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Each of N members runs with a twin at scaled distance --d0 in a random direction;\n"
                    "every --renorm seconds the growth of their separation is logged and the twin is\n"
                    "pulled back to d0 (Benettin). Writes DIR/chaos.npz (log stretches, growth curves,\n"
                    "FTLE per member) and DIR/chaos.png (growth over time, FTLE histogram), and prints\n"
                    "the FTLE's mean and spread. Coordinates are scaled by L (angles by 1 rad), rates by\n"
                    "sqrt(g L).")
    chaos.add_argument("scene", help="built-in scene name or path to a .toml scene file")
    _study_options(chaos)
    chaos.add_argument("--d0", type=_positive, default=1e-8, help="twin separation, scaled (default: 1e-8)")
    chaos.add_argument("--renorm", type=_positive, metavar="S",
                       help="seconds between renormalisations (default: 100 steps, or t-end if shorter)")
    chaos.add_argument("--out", type=_out_path, metavar="DIR", help="output folder (default: runs/<scene name>)")
    _lanes_option(chaos, "twin pairs")
    chaos.set_defaults(func=cmd_chaos)

    from . import bench as _bench

    bench = sub.add_parser("bench", help="measure step throughput, skip gains, the C ceiling, ensemble scaling",
                           description=_bench.__doc__.split("\n\n")[0])
    _bench.add_arguments(bench)
    bench.set_defaults(func=_bench.run)

    build = sub.add_parser("build", help="regenerate the generated model modules",
                           description="Regenerate the generated module of each scene: built-in "
                                       "names write generated/<name>.py, scene files write the "
                                       "cache folder (printed). Unchanged models stay byte-identical.")
    build.add_argument("scenes", nargs="*", metavar="SCENE",
                       help="built-in names or .toml paths (default: every built-in scene)")
    build.add_argument("--check", action="store_true",
                       help="write nothing; exit 1 if a built-in module is not current")
    build.set_defaults(func=cmd_build)

    scenes = sub.add_parser("scenes", help="list the built-in scenes",
                            description="List the built-in scenes with their descriptions.")
    scenes.set_defaults(func=cmd_scenes)

    cache = sub.add_parser(
        "cache", help="show where compiled code is cached and its size, prune or clear it",
        description="Generated models and compiled kernels are cached in $JACKBOX_CACHE_DIR, else "
                    "$XDG_CACHE_HOME/jackbox, else ~/.cache/jackbox. A damaged entry is found (by "
                    "checksum, or when it fails to load), removed and rebuilt with one warning; a "
                    "read-only folder is read where it is, and what must be compiled then (or when the "
                    "disk is full) is kept for the process only, with one warning. "
                    "What is not cached compiles in two processes where there are two cores "
                    "(JACKBOX_COMPILE_JOBS=1: one).")
    cache.add_argument("action", nargs="?", choices=("info", "clear", "prune"), default="info",
                       help="info (default): the folder, its files and size; clear: empty it; prune: remove "
                            "the engine builds of other versions of jackbox's engine or of Numba (an upgrade "
                            "compiles a build of its own, some 25 MiB, and leaves the old one) and the binding "
                            "parts compiled against them")
    cache.set_defaults(func=cmd_cache)
    return parser


def _simulation_options(parser, methods) -> None:
    parser.add_argument("--t-end", type=float, metavar="T", help="simulated time in s (default: the scene's)")
    parser.add_argument("--dt", type=float, help="RK4 step in s (default: the scene's)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="overrides",
                        help="change a scene value: a [params] name, a key such as restitution or "
                             "gravity, or section.key; repeatable")
    parser.add_argument("--method", choices=methods,
                        help=f"how impacts are handled: {', '.join(methods)} (default: jackbox.simulate's)")


def _study_options(parser) -> None:
    parser.add_argument("--n", type=_count, required=True, help="number of members")
    parser.add_argument("--perturb", action="append", default=[], metavar="NAME=SIZE",
                        help="perturb a start coordinate or rate (x_jack, theta_jack_dot, ...) by up to "
                             "SIZE; repeatable")
    parser.add_argument("--grid", action="store_true",
                        help="perturbations on an even grid (n = m^k for k names) instead of random")
    parser.add_argument("--sweep", action="append", default=[], metavar="NAME=FIRST:LAST",
                        help="spread a parameter (a [params] name, e, e_ground or restitution) over the "
                             "members; two --sweep make a square grid")
    parser.add_argument("--seed", type=_count0, default=0, help="random seed of the perturbations (default: 0)")
    parser.add_argument("--t-end", type=float, metavar="T", help="simulated time in s (default: the scene's)")
    parser.add_argument("--dt", type=float, help="RK4 step in s (default: the scene's)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="overrides",
                        help="change a scene value for every member (as jackbox run --set); repeatable")
    parser.add_argument("--threads", type=_count, help="Numba threads here, or per Dask worker (default: all "
                                                       "cores here, 1 per Dask worker)")
    parser.add_argument("--chunk", type=_count, help="members per kernel call / Dask task (default: 1024 with a "
                                                     "progress bar or Dask, else all at once)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--dask", choices=("local",),
                       help="local: start a Dask LocalCluster on this machine (--workers processes)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="send the chunks to a running Dask scheduler")
    parser.add_argument("--workers", type=_count, help="worker processes of --dask local (default: cores)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="cpu (default): every core here; cuda: one NVIDIA GPU thread per member (needs "
                             "the numba-cuda package: pip install 'jackbox[cuda]'), the same method")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar or summary")


def _count(text: str) -> int:
    return int(_number(text, lambda v: v >= 1 and v == int(v), "a whole number >= 1"))


def _count0(text: str) -> int:
    return int(_number(text, lambda v: v >= 0 and v == int(v), "a whole number >= 0"))


def _pairs(values: list[str], option: str, parse, form: str) -> dict:
    """NAME=VALUE pairs of an option, each value read by parse; form: what a value looks like (for the error)."""
    out = {}
    for pair in values:
        name, sep, value = pair.partition("=")
        if not sep or not name.strip():
            raise JackboxError(f"{option} {pair!r}: expected NAME=VALUE")
        try:
            out[name.strip()] = parse(value.strip())
        except ValueError:
            raise JackboxError(f"{option} {pair!r}: cannot read {value.strip()!r} (expected {form})") from None
    return out


def _span(text: str) -> tuple[float, float]:
    first, sep, last = text.partition(":")
    if not sep:
        raise ValueError(text)
    return float(first), float(last)


def _study_kwargs(args) -> dict:
    if args.workers and args.dask != "local":
        raise JackboxError("--workers goes with --dask local")
    if args.dask or args.scheduler:
        gc.enable()                 # (off in the program: see console)
    return {"perturb": _pairs(args.perturb, "--perturb", float, "a number"),
            "sweep": _pairs(args.sweep, "--sweep", _span, "LOW:HIGH, e.g. restitution=0:1"),
            "t_end": args.t_end, "dt": args.dt, "seed": args.seed, "grid": args.grid, "threads": args.threads,
            "chunk": args.chunk, "scheduler": args.scheduler, "device": args.device,
            "dask_local": (args.workers or _cores()) if args.dask == "local" else None,
            "progress": not args.quiet, "log": _say(args)}


def _study_status(completed) -> int:
    """Exit status of a study: 3 when any member did not complete (it is said in the summary)."""
    if completed.all():
        return 0
    print(f"jackbox: {int((~completed).sum())} of {len(completed)} members did not complete "
          f"(exit status {EXIT_INCOMPLETE})", file=sys.stderr)
    return EXIT_INCOMPLETE


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def cmd_ensemble(args) -> int:
    from .ensemble import ensemble
    from .scene import load_scene

    scene = load_scene(args.scene, _overrides(args.overrides))
    out_dir = _out_dir(args, scene)
    lanes = {"auto": None, "yes": True, "no": False}[args.lanes]
    result = ensemble(scene, args.n, samples=args.samples, lanes=lanes, **_study_kwargs(args))
    path = result.save(out_dir / "ensemble.npz")
    if not args.quiet:
        print(result.summary())
        print(f"wrote      {path}")
    return _study_status(result.completed)


def _lanes_option(parser, what: str) -> None:
    parser.add_argument("--lanes", choices=("auto", "yes", "no"), default="auto",
                        help=f"{what} that share their parameters (but for the restitution) fly in blocks of SIMD "
                             "lanes (the same numbers, faster): yes, no, or auto (default): where that wins back "
                             "its compile time (a big study) or it is compiled already")


def cmd_chaos(args) -> int:
    from .ensemble import chaos
    from .scene import load_scene

    scene = load_scene(args.scene, _overrides(args.overrides))
    out_dir = _out_dir(args, scene)
    lanes = {"auto": None, "yes": True, "no": False}[args.lanes]
    study = chaos(scene, args.n, d0=args.d0, renorm=args.renorm, lanes=lanes, **_study_kwargs(args))
    from . import plots

    written = [study.save(out_dir / "chaos.npz"), plots.write_chaos(study, out_dir / "chaos.png")]
    if not args.quiet:
        print(study.summary())
        for path in written:
            print(f"wrote      {path}")
    return _study_status(study.completed)


def _number(text: str, ok, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and ok(value)):
        raise argparse.ArgumentTypeError(f"must be {what}, got {text}")
    return value


def _out_path(text: str) -> Path:
    """--out: a path, not an empty string (which Path takes for the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty: name a file or folder (. for this folder)")
    return Path(text)


def _positive(text: str) -> float:
    return _number(text, lambda v: v > 0, "a number > 0")


def _non_negative(text: str) -> float:
    return _number(text, lambda v: v >= 0, "a number >= 0")


def _frames(text: str) -> int:
    value = _number(text, lambda v: v >= 2 and v == int(v), "a whole number >= 2")
    return int(value)


def _overrides(pairs: list[str]) -> dict[str, str]:
    out = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name.strip():
            raise JackboxError(f"--set {pair!r}: expected NAME=VALUE")
        out[name.strip()] = value.strip()
    return out


def _restitutions(values: list[str]) -> list[float]:
    out = []
    for text in values:
        try:
            e = float(text)
        except ValueError:
            raise JackboxError(f"--restitution {text!r}: not a number") from None
        if not (math.isfinite(e) and 0.0 <= e <= 1.0):
            raise JackboxError(f"--restitution {text}: must be in [0, 1] (1 elastic, 0 plastic)")
        if e in out:
            raise JackboxError(f"--restitution {text}: given twice")
        out.append(e)
    if len(out) < 2:
        raise JackboxError("--restitution: give two or more values to compare, e.g. --restitution 1.0 0.6")
    return out


def _out_dir(args, scene) -> Path:
    out_dir = args.out if args.out is not None else Path("runs") / scene.name
    if out_dir.exists() and not out_dir.is_dir():
        raise JackboxError(f"--out {out_dir}: exists and is not a folder")
    check_writable(out_dir)
    return out_dir


def _out_file(out: Path | None, source: Path, run_name: str, suffix: str) -> Path:
    """``--out``, else the picture beside its trajectory: ``run_name`` for a run's
    ``trajectory.npz``, else the file's own name with ``suffix``."""
    path = out if out is not None else (
        source.with_name(run_name) if source.stem == "trajectory" else source.with_suffix(suffix))
    if path.is_dir():
        raise JackboxError(f"--out {path}: is a folder (give a file name)")
    check_writable(path.parent)
    return path


def _simulate_kwargs(args) -> dict:
    # pass the method only when asked: otherwise jackbox.simulate's default applies
    return {"method": args.method} if args.method else {}


def _say(args):
    return (lambda *a: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))


def cmd_run(args) -> int:
    from .api import simulate
    from .scene import load_scene

    scene = load_scene(args.scene, _overrides(args.overrides))
    out_dir = _out_dir(args, scene)
    t0 = time.perf_counter()
    traj = simulate(scene, t_end=args.t_end, dt=args.dt, record_every=args.record_every,
                    progress=not args.quiet, log=_say(args), **_simulate_kwargs(args))
    wall = time.perf_counter() - t0
    written = [traj.save(out_dir / "trajectory.npz")]
    if not args.no_plots:
        written += _pictures(traj, scene, out_dir, progress=not args.quiet, plotlyjs=args.plotlyjs)
    # a folder never mixes two runs: pictures of an older one beside this trajectory go
    removed = [out_dir / name for name in RUN_PICTURES
               if out_dir / name not in written and (out_dir / name).exists()]
    for path in removed:
        path.unlink()
    if not args.quiet:
        k = traj.meta["kernel"]
        steps = traj.meta["n_steps"]
        print(f"scene      {scene.name} ({scene.source})")
        print(f"steps      {steps} of dt = {traj.meta['dt']:g} s to t = {traj.t[-1]:g} s, method {traj.meta['method']}")
        print(f"impacts    {len(traj.impact_t)} impulses"
              + (f", first at t = {traj.impact_t[0]:.4g} s" if len(traj.impact_t) else ""))
        print(f"energy     {traj.energy[0]:.10g} J at start, {traj.energy[-1]:.10g} J at end")
        if traj.meta.get("fallback_seconds"):
            reasons = sorted(set(traj.meta.get("fallback_reasons", [])))
            print(f"fallback   {traj.meta['fallback_seconds']:.4g} s integrated by the fallback (Moreau-Jean, "
                  f"first order)" + (f": {'; '.join(reasons)}" if reasons else ""))
        how = {"hit": "loaded from cache", "miss": "compiled", "memory": "in memory",
               "disabled": "not compiled (NUMBA_DISABLE_JIT)"}[k["cache"]]
        print(f"wall time  {wall:.3f} s (kernel {how} "
              f"in {k['load_seconds']:.2f} s, ran in {k['run_seconds']:.3f} s)")
        if k["steps_per_second"]:
            print(f"speed      {k['steps_per_second']:.3g} steps/s")
        for path in written:
            print(f"wrote      {path}")
        for path in removed:
            print(f"removed    {path} (an older run's)")
    return 0


#: the pictures `jackbox run` writes beside trajectory.npz (and the library its page loads)
RUN_PICTURES = ("timeseries.png", "animation.html", "plotly.min.js")


def _pictures(traj, scene, out_dir: Path, progress: bool, plotlyjs: str = "beside") -> list[Path]:
    """timeseries.png and animation.html of a run, beside its trajectory (and plotly.min.js, if beside)."""
    from . import animate, plots
    from .geometry import Geometry

    geometry = Geometry.from_scene(scene, traj.meta.get("params"))
    png = plots.write_timeseries(traj, out_dir / "timeseries.png", geometry)
    html = animate.write_animation(traj, out_dir / "animation.html", geometry=geometry, progress=progress,
                                   plotlyjs=plotlyjs)
    return [png, html] + ([out_dir / animate.PLOTLYJS_NAME] if plotlyjs == "beside" else [])


def cmd_compare(args) -> int:
    from .api import simulate
    from .scene import load_scene

    values = _restitutions(args.restitution)
    scene = load_scene(args.scene, _overrides(args.overrides))
    out_dir = _out_dir(args, scene)
    trajs = []
    for e in values:
        trajs.append(simulate(scene, t_end=args.t_end, dt=args.dt, params={"e": e, "e_ground": e},
                              progress=not args.quiet, log=_say(args), **_simulate_kwargs(args)))
    from . import plots

    labels = [f"e = {e:g}" for e in values]
    path = plots.write_comparison(trajs, labels, out_dir / "comparison.png")
    if not args.quiet:
        first = trajs[0]
        print(f"scene      {scene.name} ({scene.source}), method {first.meta['method']}, "
              f"dt = {first.meta['dt']:g} s, t = {first.t[0]:g}..{first.t[-1]:g} s")
        print("           each run sets e (jack-wall) and e_ground (box-ground) to its value")
        print(plots.summary_table([plots.summarize(tr, f"{e:g}") for tr, e in zip(trajs, values)]))
        print(f"wrote      {path}")
    return 0


def _load_trajectory(path: Path):
    from .trajectory import Trajectory

    if path.is_dir():
        raise JackboxError(f"{path}: is a folder, not a trajectory .npz")
    return Trajectory.load(path)


def cmd_animate(args) -> int:
    from . import animate

    out = _out_file(args.out, args.file, "animation.html", ".html")
    if out.suffix.lower() not in (".html", ".htm"):
        raise JackboxError(f"{out}: an animation is written as an .html page, not "
                           f"{out.suffix or 'a name without an extension'}")
    traj = _load_trajectory(args.file)
    path = animate.write_animation(traj, out, plotlyjs=args.plotlyjs, fps=args.fps, speed=args.speed,
                                   max_frames=args.max_frames, trail=args.trail, progress=not args.quiet)
    if not args.quiet:
        print(f"wrote      {path}")
    return 0


def cmd_plot(args) -> int:
    from . import plots

    out = _out_file(args.out, args.file, "timeseries.png", ".png")
    plots.figure_format(out)      # png, pdf or svg: refused before any work
    traj = _load_trajectory(args.file)
    path = plots.write_timeseries(traj, out)
    if not args.quiet:
        print(f"wrote      {path}")
    return 0


def cmd_build(args) -> int:
    from codegen import model_hash

    from .loader import GENERATED_DIR, build_model, model_path, recorded_hash
    from .scene import builtin_scenes, load_scene

    names = args.scenes or list(builtin_scenes())
    stale = 0
    for name in names:
        scene = load_scene(name)
        target = GENERATED_DIR / f"{scene.name}.py" if scene.builtin else model_path(scene)
        if not scene.builtin and target.parent == GENERATED_DIR:
            # same structure as a built-in: its committed module serves it, nothing to write
            print(f"current    {target}  (the structure of {name} is that of a built-in scene)")
            continue
        if args.check:
            current = recorded_hash(target) == model_hash(scene.structure())
            stale += not current
            print(f"{'current' if current else 'STALE  '}  {target}")
            continue
        result = build_model(scene, target)
        print(f"{'wrote    ' if result.changed else 'unchanged'}  {target}  "
              f"(derive {result.seconds['derive']:.2f} s, cse + emit {result.seconds['cse_emit']:.2f} s)")
    return 1 if stale else 0


def _tree_size(folder) -> tuple[int, int]:
    """The files under `folder` and their bytes (none where it does not exist)."""
    files = [f for f in folder.rglob("*") if f.is_file()] if folder.is_dir() else []
    return len(files), sum(f.stat().st_size for f in files)


def cmd_cache(args) -> int:
    import shutil

    from .loader import configured_cache_dir, parts_of_other_engines

    folder = configured_cache_dir()
    if args.action == "prune":           # (the old builds only: not a walk of the whole cache)
        from .engine.cache import DIGEST

        old = [p for p in sorted(folder.glob("engine/*")) if p.is_dir() and p.name != DIGEST]
        freed = sum(_tree_size(p)[1] for p in old)
        for p in old:
            shutil.rmtree(p)
        parts = parts_of_other_engines(folder / "kernels", DIGEST)
        freed_parts = 0
        for p in parts:
            try:
                freed_parts += p.stat().st_size
                p.unlink()
            except OSError:
                pass                     # (gone already, or not ours to remove: left)
        print(f"pruned     {len(old)} engine build(s) of other versions ({freed / 2**20:.1f} MiB) and "
              f"{len(parts)} file(s) of binding parts made for them ({freed_parts / 2**20:.1f} MiB) from {folder}; "
              f"kept this one's ({DIGEST})")
        return 0
    n_files, size = _tree_size(folder)
    if args.action == "clear":
        for part in ("models", "kernels", "engine"):      # only what jackbox writes there
            if (folder / part).is_dir():
                shutil.rmtree(folder / part)
        print(f"cleared    {folder} ({n_files} files, {size / 2**20:.1f} MiB)")
        return 0
    models = len(list(folder.glob("models/*.py")))
    functions = len(list(folder.glob("kernels/*.py")))
    engines = len([p for p in folder.glob("engine/*") if p.is_dir()])
    print(f"cache      {folder}{'' if folder.is_dir() else ' (not created yet)'}")
    print(f"holds      {models} generated models, {functions} binding parts (a model's functions, compiled "
          f"one by one), "
          f"{engines} engine build(s), {n_files} files, {size / 2**20:.1f} MiB")
    return 0


def cmd_scenes(args) -> int:
    from .scene import builtin_scenes, load_scene

    for name in builtin_scenes():
        scene = load_scene(name)
        print(f"{name:10s} {scene.description}  [{scene.t_end:g} s, dt {scene.dt:g}]")
    return 0


if __name__ == "__main__":
    console()
