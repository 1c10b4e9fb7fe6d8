"""`simreel view`: one episode of a recording as a Rerun session — saved .rrd, native viewer or web viewer."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

from simreel.cli.common import add_import_option, add_tolerance_options, refuse_tolerances_without_compare
from simreel.errors import UsageError
from simreel.io.durable import raise_if_stopped

__all__ = ["add_parser", "run", "default_output", "has_display", "open_command", "open_hint", "viewer_available"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "view",
        help="view an episode in Rerun (3D scene, contacts, plots, overlay of a replay or another recording)",
        description=(
            "Turn one episode of a recording (.h5 or .mcap) into a Rerun session: the scene in 3D over the "
            "`step` and `sim_time` timelines, contact-force arrows, plots of reward/success/qpos/contacts, camera "
            "images, and with --compare another recording's episode (a replay, a conversion, a second recording) "
            "as a translucent ghost under compared/ with its error per state key, named as what it is: `replay` "
            "(simreel replay -o of PATH), `conversion` (simreel convert of PATH), else its file name."
        ),
    )
    p.add_argument("paths", nargs="+", metavar="PATH",
                   help="recording (.h5 or .mcap); with --serve, several: one Rerun recording per file and episode")
    p.add_argument("--episode", type=int, action="append", default=None, metavar="I",
                   help="episode index (default: the first in the file); see `simreel inspect PATH`. With --serve, "
                        "give it more than once to serve several episodes (of each PATH), picked in the viewer")
    p.add_argument("--compare", default=None, metavar="OTHER",
                   help="another recording of the task: a replay (`simreel replay -o OTHER`), a conversion or a "
                        "second recording; ghost overlay + first divergence")
    add_tolerance_options(p, mode_default=None,
                          mode_help="whose default tolerances judge --compare (as `simreel replay --mode`). Default, "
                                    "with no --atol/--tol either: a replay or conversion of PATH is judged with the "
                                    "tolerances that judged it when it was written, any other file with actions'")
    sink = p.add_mutually_exclusive_group()
    sink.add_argument("--save", default=None, metavar="OUT.rrd",
                      help="write a .rrd file (the default when no viewer can be opened: <recording>.episode<I>.rrd)")
    sink.add_argument("--spawn", action="store_true", help="open the native Rerun viewer")
    sink.add_argument("--serve", action="store_true",
                      help="serve the episode to the web viewer (for a remote machine) until Ctrl-C or SIGTERM")
    p.add_argument("--web-port", type=int, default=None, help=f"web viewer port for --serve (default {_PORTS['web']})")
    p.add_argument("--bind", default=None, metavar="ADDRESS",
                   help="the address --serve listens on (default 127.0.0.1: this machine only, reached from another "
                        "through ssh -L; 0.0.0.0: every interface, for anyone who can reach this machine)"),
    p.add_argument("--grpc-port", type=int, default=None,
                   help=f"gRPC port for --serve/--spawn (default {_PORTS['grpc']})")
    p.add_argument("--server-memory-limit", default=None, metavar="LIMIT",
                   help="the most memory the --serve server keeps the episodes in, e.g. 2GB or 25%% (past it, the "
                        "oldest data is dropped; default: Rerun's)")
    p.add_argument("--geometry", default="auto", choices=("auto", "visual", "collision"),
                   help="visual meshes (needs a render device), collision shapes, or auto (default)")
    p.add_argument("--block-steps", type=int, default=None, metavar="N",
                   help="steps read and logged per block; bounds memory on long episodes (default: about 4 MiB of "
                        "rows)")
    p.add_argument("--overwrite", action="store_true", help="replace the .rrd file if it exists")
    add_import_option(p, reads_recordings=True)
    p.set_defaults(run=run)


def has_display() -> bool:
    """Whether a window can open here: macOS and Windows always; elsewhere an X11 or Wayland display that answers."""
    return display_problem() is None


def display_problem() -> str | None:
    """Why no window can open here (None: one can). A display that is set is probed: a viewer spawned onto a display
    nothing serves would bind its port and exit, which is only seen after a race with the stream."""
    if sys.platform in ("darwin", "win32"):
        return None
    x11, wayland = os.environ.get("DISPLAY"), os.environ.get("WAYLAND_DISPLAY")
    if os.environ.get("WAYLAND_SOCKET") or (wayland and _wayland_answers(wayland)) or (x11 and _x11_answers(x11)):
        return None
    if not x11 and not wayland:
        return "there is no display here (DISPLAY and WAYLAND_DISPLAY are unset)"
    shown = ", ".join(f"{name}={value}" for name, value in (("DISPLAY", x11), ("WAYLAND_DISPLAY", wayland)) if value)
    return f"no display server answers at {shown}"


def _x11_answers(display: str) -> bool:
    """Whether an X server accepts connections for `display` ("[host]:N[.screen]"): its Unix socket, Linux's abstract
    one, or TCP port 6000+N on the host."""
    import socket

    host, _, number = display.rpartition(":")
    number = number.split(".")[0]
    if not number.isdigit():
        return True  # a form this probe does not know: let the viewer try
    if host in ("", "unix"):
        targets = [(socket.AF_UNIX, f"/tmp/.X11-unix/X{number}"), (socket.AF_UNIX, f"\0/tmp/.X11-unix/X{number}")]
    else:
        targets = [(socket.AF_INET, (host, 6000 + int(number)))]
    return any(_accepts(family, address) for family, address in targets)


def _wayland_answers(name: str) -> bool:
    """Whether a Wayland compositor accepts connections on socket `name` (in $XDG_RUNTIME_DIR unless absolute)."""
    import socket

    folder = os.environ.get("XDG_RUNTIME_DIR", "")
    return _accepts(socket.AF_UNIX, name if name.startswith("/") else os.path.join(folder, name))


def _accepts(family: int, address: object) -> bool:
    import socket

    try:
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.settimeout(1.0)
            s.connect(address)
        return True
    except OSError:
        return False


def viewer_available() -> bool:
    """Whether the native viewer could open a window here: a display and the `rerun` executable."""
    from simreel.viewers.session import viewer_executable

    return has_display() and viewer_executable() is not None


def _check_spawn() -> None:
    """`--spawn` without a display or without the viewer is bad input, refused before any work."""
    from simreel.viewers.session import viewer_executable

    problem = display_problem()
    if problem is not None:
        raise UsageError(f"--spawn opens the Rerun viewer in a window, and {problem}; write the session with --save "
                         "OUT.rrd and open it where there is one, or serve it to a browser with --serve")
    if viewer_executable() is None:
        raise UsageError("--spawn: the Rerun viewer (`rerun`, installed with rerun-sdk) is neither on PATH nor "
                         f"beside {sys.executable}; write the session with --save OUT.rrd, or use --serve")


def open_command(rrd: str | Path) -> str:
    """The shell command that opens `rrd` in the Rerun viewer simreel itself uses (`viewer_executable`).

    ``rerun FILE`` where `rerun` on PATH is that viewer (an activated venv), else the viewer by its path, relative
    to the current folder when it lies inside it: ``.venv/bin/rerun FILE`` in the repository root, where
    ``make demo`` runs. Either way the command works in the shell simreel was started from.
    """
    import shlex

    return f"{viewer_command()} {shlex.quote(str(rrd))}"


def viewer_command() -> str:
    """The Rerun viewer as the shell simreel was started from reaches it (`open_command`), shell-quoted."""
    import shlex
    import shutil

    from simreel.viewers.session import viewer_executable

    viewer = viewer_executable()
    if viewer is None or viewer == shutil.which("rerun"):
        return "rerun"
    relative = os.path.relpath(viewer)
    return shlex.quote(viewer if relative.startswith("..") else relative if os.sep in relative else f"./{relative}")


def open_hint(rrd: str | Path) -> list[str]:
    """The lines that say how to look at a saved .rrd here: ``open it with: <open_command>`` where a window can
    open; elsewhere the command that serves it to a browser, the URL (WebGL: a browser without a GPU cannot run
    Rerun's WebGPU renderer) and the ssh port forward for a browser on another machine."""
    if has_display():
        return [f"open it with: {open_command(rrd)}"]
    from simreel.viewers.web_server import port_forward_line, serve_file_command, web_viewer_url

    web, grpc = _PORTS["web"], _PORTS["grpc"]
    return [f"no display here; serve it to a browser with: {serve_file_command(viewer_command(), str(rrd))}",
            f"then open: {web_viewer_url(web, f'rerun+http://127.0.0.1:{grpc}/proxy')}",
            port_forward_line(web, grpc)]


def default_output(path: str | Path, episode: int) -> Path:
    """``<recording stem>.episode<I>.rrd`` in the current folder."""
    return Path.cwd() / f"{Path(path).stem}.episode{episode}.rrd"


def _shown_episodes(args: argparse.Namespace) -> list[tuple[str, int]]:
    """(file, episode) of each session to show; a bad file or episode fails here, before any env is built. Several
    only with --serve (one server holds them all)."""
    from simreel.formats import open_reader

    several = len(args.paths) > 1 or len(args.episode or ()) > 1
    if several and not args.serve:
        raise UsageError("several recordings or episodes are shown together only with --serve (one web viewer, one "
                         "Rerun recording each); otherwise give one PATH and one --episode")
    if several and args.compare is not None:
        raise UsageError("--compare overlays another recording on one episode: give one PATH and one --episode")
    shown = []
    for path in dict.fromkeys(args.paths):  # each once, in the order given
        with open_reader(path) as reader:
            for episode in dict.fromkeys(args.episode or [reader.episodes[0].index if reader.episodes else 0]):
                reader.episode_meta(episode)
                shown.append((path, episode))
    return shown


_PORTS = {"web": 9090, "grpc": 9876}
"""The ports --serve (web and gRPC) and --spawn (gRPC) use unless --web-port / --grpc-port say otherwise."""


def _refuse_unused(args: argparse.Namespace, mode: str) -> None:
    """`UsageError` for an option that would be ignored, silently, with the others given: tolerances without
    --compare (`refuse_tolerances_without_compare`), ports where no server runs (--save; --web-port with --spawn).
    Then the ports not given are the defaults (`_PORTS`)."""
    refuse_tolerances_without_compare(args)
    serverless = {"save": ("--web-port", "--grpc-port", "--server-memory-limit"),
                  "spawn": ("--web-port", "--server-memory-limit"), "serve": ()}[mode]
    unused = ", ".join(option for option in serverless if getattr(args, option[2:].replace("-", "_")) is not None)
    if unused and mode == "spawn":
        raise UsageError(f"{unused}: of the web server, for --serve; --spawn uses --grpc-port only")
    if unused:
        shown = "--save" if args.save else "the default --save (no viewer can open here)"
        what = "options of the servers" if "memory" in unused else "ports"
        raise UsageError(f"{unused}: {what} of --serve and --spawn; with {shown} no server runs, so leave {unused} "
                         "out")
    if args.bind is not None and mode != "serve":
        raise UsageError(f"--bind {args.bind}: the address --serve listens on; with --{mode} it would be ignored, "
                         "so leave it out")
    if args.server_memory_limit is not None:
        from simreel.viewers.web_server import check_memory_limit

        args.server_memory_limit = check_memory_limit(args.server_memory_limit)
    args.web_port = _PORTS["web"] if args.web_port is None else args.web_port
    args.grpc_port = _PORTS["grpc"] if args.grpc_port is None else args.grpc_port


def _sink(args: argparse.Namespace, episode: int) -> tuple[str, str | None]:
    """("save", the .rrd path) or ("spawn" | "serve", None); an .rrd is checked before any work."""
    from simreel.viewers.session import check_rrd_target

    mode = "save" if args.save is not None else "spawn" if args.spawn else "serve" if args.serve else None
    save = args.save
    if mode is None:
        mode = "spawn" if viewer_available() else "save"
        if mode == "save":
            save = str(default_output(args.path, episode))
    _refuse_unused(args, mode)
    if mode == "save":
        shown = [args.path] + ([args.compare] if args.compare is not None else [])
        check_rrd_target(save, overwrite=args.overwrite, shown=shown)
    elif mode == "spawn":
        _check_spawn()
    else:
        _check_ports(args)
    return mode, save


def _check_ports(args: argparse.Namespace) -> None:
    """`--serve`'s ports must be free: Rerun reports a busy gRPC port only in its log, and serves nothing."""
    import socket

    from simreel.viewers.web_server import LOCALHOST, check_bind_address

    args.bind = check_bind_address(LOCALHOST if args.bind is None else args.bind)
    if args.web_port == args.grpc_port:
        raise UsageError(f"--web-port and --grpc-port are both {args.web_port}; the two servers need two ports")
    for option, port in (("--web-port", args.web_port), ("--grpc-port", args.grpc_port)):
        if not 0 < port < 65536:
            raise UsageError(f"{option} {port}: a port is a number from 1 to 65535")
        with socket.socket(socket.AF_INET6 if ":" in args.bind else socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as servers bind: TIME_WAIT is no obstacle
            try:
                probe.bind((args.bind, port))  # where the servers will listen
            except OSError as e:
                raise UsageError(f"{option} {port}: the port is taken ({e.strerror}); choose a free one with "
                                 f"{option} N") from None


def run(args: argparse.Namespace) -> int:
    if args.block_steps is not None and args.block_steps < 1:
        raise UsageError(f"--block-steps must be ≥ 1, got {args.block_steps}")
    args.path = args.paths[0]
    shown = _shown_episodes(args)
    mode, save = _sink(args, shown[0][1])
    if mode == "serve":
        return _serve(args, shown)
    t0 = time.perf_counter()
    with _built_session(args, *shown[0]) as session:
        if mode == "save":
            out = session.save(save, overwrite=args.overwrite)
            size = out.stat().st_size / 1024
            print(f"wrote {out} ({size:.0f} KiB, {session.episode.length} steps, {session.geometry_source} geometry) "
                  f"in {time.perf_counter() - t0:.1f} s")
        else:
            session.spawn(port=args.grpc_port)
            print(f"sent {session.recording_id} to the Rerun viewer")
        _print_lines(_findings(session))
        if mode == "save":
            _print_lines(open_hint(out))
    return 0


def _built_session(args: argparse.Namespace, path: str, episode: int) -> Any:
    """The session of one episode, built as the options say (a warning when visual meshes cannot be had)."""
    from simreel.viewers import ViewOptions, build_session

    options = ViewOptions(episode=episode, compare=args.compare, geometry=args.geometry, mode=args.mode,
                          atol=args.atol, tolerances=dict(args.tol) or None, block_steps=args.block_steps,
                          imports=tuple(args.imports), trust_recorded_imports=args.trust_recorded_imports)
    session = build_session(path, options)
    if args.geometry == "visual" and session.geometry_source != "visual":
        from simreel.sim.make import no_render_device_fix

        print("warning: no render device, so no visual meshes: showing collision shapes (for the meshes, "
              f"{no_render_device_fix()})", file=sys.stderr)
    with session.closed_on_error():
        raise_if_stopped()  # a Ctrl-C a library swallowed while the session was built
    return session


def _serve(args: argparse.Namespace, shown: list[tuple[str, int]]) -> int:
    """Serve every (file, episode) of `shown` from one server, one Rerun recording each, until Ctrl-C or SIGTERM;
    each session's env is closed once it is streamed (the server holds what was sent)."""
    from simreel.viewers.web_server import LOCALHOST, port_forward_line, start_web_server

    server = start_web_server(bind=args.bind, web_port=args.web_port, grpc_port=args.grpc_port,
                              memory_limit=args.server_memory_limit)
    try:
        served, findings = [], []
        for path, episode in shown:
            with _built_session(args, path, episode) as session:
                url = session.stream_to(server)
                served.append(session.recording_id)
                said = _findings(session)
                findings += [f"{session.recording_id}: {line}" for line in said] if len(shown) > 1 else said
        print(f"serving {', '.join(served)} at {url} (Ctrl-C to stop)")
        _print_lines(findings)
        if len(served) > 1:
            print(f"{len(served)} recordings: pick one in the viewer's recordings panel (top left)")
        print(f"ports: web viewer {server.web_port}, gRPC {server.grpc_port}, on {server.bind}")
        if server.bind == LOCALHOST:
            print(port_forward_line(server.web_port, server.grpc_port))
        sys.stdout.flush()
        print(f"stopped serving ({_wait_for_stop()})")
    finally:
        server.close()
    return 0


def _print_lines(lines: list[str]) -> None:
    for line in lines:
        print(line)


def _findings(session: Any) -> list[str]:
    """The notes of the episode shown and what the comparison found, as lines."""
    import contextlib
    import io

    said = io.StringIO()
    with contextlib.redirect_stdout(said):
        for note in session.episode.meta.notes:
            print(f"note: {note}")
        _print_comparison(session.comparison, session.explanation, session.compared)
    return said.getvalue().splitlines()


class _Stop(Exception):
    """Raised in the main thread by the SIGTERM handler `_wait_for_stop` installs."""


def _wait_for_stop() -> str:
    """Block until Ctrl-C (SIGINT) or SIGTERM, and say which came."""
    import signal

    def stop(signum: int, frame: Any) -> None:
        raise _Stop(signal.Signals(signum).name)

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return "Ctrl-C"
    except _Stop as e:
        return str(e)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _print_comparison(c: Any, explanation: Any, compared: Any) -> None:
    """The comparison's lines, said of `compared` (`EpisodeRun.subject`: ``replay exact``, ``second.h5 diverges``)."""
    if c is None:
        return
    subject = compared.subject
    if c.note:
        print(f"note: {c.note}")
    if c.judged_with:
        print(f"note: {c.judged_with}")
    d = c.divergence
    if d is not None:
        print(d.sentence(f"{subject} diverges"))
    elif c.unchecked_steps and c.steps:
        print(f"{subject} {c.verdict()}; steps {c.steps} to {c.steps + c.unchecked_steps - 1} were not checked")
    else:
        print(f"{subject} {c.verdict()}" + ("" if c.unchecked_steps else ": no value leaves its tolerance"))
    if explanation is not None and explanation.cause is not None:
        print(f"why: {explanation.cause.summary} (the events log shows the evidence)")

