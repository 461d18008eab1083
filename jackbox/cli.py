"""The ``jackbox`` command: run scenes, regenerate their kernels, list them.

Mistakes that are the user's (a bad scene, a missing file, a bad ``--set``)
print one ``jackbox: error: ...`` line and exit with status 2; nothing is
written. A run that goes wrong (the state turns non-finite) exits with status 1.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from . import __version__
from .errors import JackboxError, NonFiniteStateError

EPILOG = """\
examples:
  jackbox run                          run the built-in scene 'shaken'
  jackbox run drop --set restitution=0.6 --t-end 3
  jackbox run my_scene.toml --out results/
  jackbox build                        regenerate generated/ for the built-in scenes
  jackbox scenes                       list the built-in scenes
"""


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except JackboxError as exc:
        print(f"jackbox: error: {exc}", file=sys.stderr)
        return 1 if isinstance(exc, NonFiniteStateError) else 2
    except OSError as exc:
        where = f" {exc.filename}" if exc.filename else ""
        print(f"jackbox: error:{where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jackbox: interrupted", file=sys.stderr)
        return 130


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jackbox", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG,
        description="Simulate a jack bouncing in a box: scenes are compiled to Numba kernels.")
    parser.add_argument("--version", action="version", version=f"jackbox {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    run = sub.add_parser("run", help="simulate a scene and write its trajectory",
                         description="Simulate a scene (default: shaken), print a summary and write "
                                     "DIR/trajectory.npz (its keys: docs/scenes.md).")
    run.add_argument("scene", nargs="?", default="shaken",
                     help="built-in scene name or path to a .toml scene file (default: shaken)")
    run.add_argument("--t-end", type=float, metavar="T", help="simulated time in s (default: the scene's)")
    run.add_argument("--dt", type=float, help="RK4 step in s (default: the scene's)")
    run.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="overrides",
                     help="change a scene value: a [params] name, a key such as restitution or "
                          "gravity, or section.key; repeatable")
    run.add_argument("--record-every", type=int, default=1, metavar="K",
                     help="keep every K-th step in the output (default: 1)")
    run.add_argument("--out", type=Path, metavar="DIR",
                     help="output folder (default: runs/<scene name>)")
    run.add_argument("--quiet", "-q", action="store_true", help="no progress bar or summary")
    run.set_defaults(func=cmd_run)

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
    return parser


def _overrides(pairs: list[str]) -> dict[str, str]:
    out = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name.strip():
            raise JackboxError(f"--set {pair!r}: expected NAME=VALUE")
        out[name.strip()] = value.strip()
    return out


def cmd_run(args) -> int:
    from .api import simulate
    from .scene import load_scene

    scene = load_scene(args.scene, _overrides(args.overrides))
    out_dir = args.out if args.out is not None else Path("runs") / scene.name
    if out_dir.exists() and not out_dir.is_dir():
        raise JackboxError(f"--out {out_dir}: exists and is not a folder")
    say = (lambda *a: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    t0 = time.perf_counter()
    traj = simulate(scene, t_end=args.t_end, dt=args.dt, record_every=args.record_every,
                    progress=not args.quiet, log=say)
    wall = time.perf_counter() - t0
    path = traj.save(out_dir / "trajectory.npz")
    if not args.quiet:
        k = traj.meta["kernel"]
        steps = traj.meta["n_steps"]
        print(f"scene      {scene.name} ({scene.source})")
        print(f"steps      {steps} of dt = {traj.meta['dt']:g} s to t = {traj.t[-1]:g} s, method {traj.meta['method']}")
        print(f"impacts    {len(traj.impact_t)} impulses"
              + (f", first at t = {traj.impact_t[0]:.4g} s" if len(traj.impact_t) else ""))
        print(f"energy     {traj.energy[0]:.10g} J at start, {traj.energy[-1]:.10g} J at end")
        how = {"hit": "loaded from cache", "miss": "compiled", "memory": "in memory",
               "disabled": "not compiled (NUMBA_DISABLE_JIT)"}[k["cache"]]
        print(f"wall time  {wall:.3f} s (kernel {how} "
              f"in {k['load_seconds']:.2f} s, ran in {k['run_seconds']:.3f} s)")
        if k["steps_per_second"]:
            print(f"speed      {k['steps_per_second']:.3g} steps/s")
        print(f"wrote      {path}")
    return 0


def cmd_build(args) -> int:
    from codegen.driver import build
    from codegen.version import model_hash

    from .loader import GENERATED_DIR, model_path, recorded_hash
    from .scene import builtin_scenes, load_scene

    names = args.scenes or list(builtin_scenes())
    stale = 0
    for name in names:
        scene = load_scene(name)
        target = GENERATED_DIR / f"{scene.name}.py" if scene.builtin else model_path(scene)
        if args.check:
            current = recorded_hash(target) == model_hash(scene.structure())
            stale += not current
            print(f"{'current' if current else 'STALE  '}  {target}")
            continue
        result = build(scene, target)
        print(f"{'wrote    ' if result.changed else 'unchanged'}  {target}  "
              f"(derive {result.seconds['derive']:.2f} s, cse + emit {result.seconds['cse_emit']:.2f} s)")
    return 1 if stale else 0


def cmd_scenes(args) -> int:
    from .scene import builtin_scenes, load_scene

    for name in builtin_scenes():
        scene = load_scene(name)
        print(f"{name:10s} {scene.description}  [{scene.t_end:g} s, dt {scene.dt:g}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
