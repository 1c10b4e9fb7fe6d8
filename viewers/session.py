"""A Rerun session of one recorded episode: `build_session` prepares it, `ViewSession` logs it to a sink.

Preparing reads a summary of the episode (`simreel.viewers.sources`: its per-step values and controller states) and,
for ``compare``, compares it with the other file's episode a block of rows at a time; it rebuilds the recorded env on the
CPU with one sub-scene, resets it to the episode's scene and reads the scene's geometry. Logging then sends the
geometry once (static) and reads and sends everything per step in blocks of `block_steps` rows through
`send_columns` (poses, camera frames, plots, contacts), so memory for an episode's states, frames and derived data
stays bounded by one block whatever its length.
One episode is one Rerun recording (recording id ``<file name>#episode-<index>``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from simreel.errors import UsageError, ViewError
from simreel.formats import EpisodeReader
from simreel.io.targets import staged_output
from simreel.model.components import Tolerances
from simreel.model.episode import Episode
from simreel.model.meta import RecordingMeta
from simreel.options.checks import check_flag, is_whole_number, options_with
from simreel.sim.rebuild import GYM_MAKE_SEED, UNSEEDED_WITHOUT_STATES, reset_to_episode
from simreel.sim.state import check_rebuilt_layout, read_state
from simreel.sim.user_code import import_specs
from simreel.verdicts.divergence import Explanation
from simreel.viewers.compare import (
    DEFAULT_MODE,
    ViewComparison,
    compare_for_view,
    divergence_row,
    explain_for_view,
    judging_tolerances,
)
from simreel.viewers.paths import step_of_row
from simreel.viewers.rrd_file import first_line, write_rrd
from simreel.viewers.scene_geometry import (
    GEOMETRY_SOURCES,
    BodyGeometry,
    SceneBody,
    scene_bodies,
    scene_geometry,
)
from simreel.viewers.sources import EpisodeRun, Source, read_compare, read_run
from simreel.viewers.web_server import LOCALHOST, listening, reached_at, web_viewer_url

if TYPE_CHECKING:
    import rerun as rr
    import rerun.blueprint as rrb

    from simreel.viewers.blueprint import Layout

__all__ = [
    "APPLICATION_ID",
    "ViewError",
    "ViewOptions",
    "ViewSession",
    "build_session",
    "check_rrd_target",
    "rebuild_env",
    "viewer_executable",
    "web_viewer_url",
]

APPLICATION_ID = "simreel"


@dataclass(frozen=True)
class ViewOptions:
    """What `build_session` shows and how.

    Attributes:
        episode: the episode's index (default: the first episode in the file).
        compare: another recording of the same env (a replay written by ``simreel replay -o``, a conversion, a
            second recording): its episode drawn as a translucent ghost under ``compared/``, with the per-key state
            error and its first divergence, named as what it is (`simreel.viewers.sources.EpisodeRun.subject`). The
            episode with the same index is used (never another).
        geometry: ``"auto"`` (visual shapes when a render device exists, else collision shapes),
            ``"visual"`` or ``"collision"``.
        mode, atol, tolerances: the comparison's tolerances, as for ``simreel replay --mode/--atol/--tol``: the
            defaults of `mode` (``actions``, ``states`` or ``step``; None: actions'), `atol` for every group, then
            per-group overrides such as ``{"pos": 1e-4}`` (see `simreel.model.components.Tolerances.for_mode`). With none
            of them, a `compare` file that is a replay or a conversion of this recording is judged with the
            tolerances that judged it when it was written (`simreel.viewers.compare.judging_tolerances`).
        block_steps: steps per block read from the files, compared and sent with `send_columns` (bounds the memory of
            observations and derived data); None: `simreel.formats.base.block_rows` of the recording (~4 MiB).
        imports: ``--import`` specs that register the task, used instead of those the recording names.
        trust_recorded_imports: import the code the recording names (``--trust-recorded-imports``); without it, or
            `imports`, only modules installed in this Python are (`simreel.sim.user_code.refuse_untrusted_imports`).
    """

    episode: int | None = None
    compare: Source | None = None
    geometry: str = "auto"
    mode: str | None = None
    atol: float | None = None
    tolerances: dict[str, float] | None = None
    block_steps: int | None = None
    imports: tuple[str, ...] = ()
    trust_recorded_imports: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "imports", import_specs(self.imports))
        check_flag("trust_recorded_imports", self.trust_recorded_imports)

    def check(self) -> Tolerances | None:
        """The tolerances asked for (None: none were; `judging_tolerances` then chooses); `UsageError` for a bad
        geometry source, block size or tolerance."""
        if self.geometry not in GEOMETRY_SOURCES:
            raise UsageError(f"--geometry {self.geometry!r}: expected one of {', '.join(GEOMETRY_SOURCES)}")
        episode = self.episode
        if episode is not None and not is_whole_number(episode):
            raise UsageError(f"episode={episode!r}: give the episode's index, an int (`simreel inspect` lists them)")
        steps = self.block_steps
        if steps is not None and not (is_whole_number(steps) and steps >= 1):
            raise UsageError(f"block_steps must be an int ≥ 1, got {steps!r}")
        if self.tolerances is not None and not isinstance(self.tolerances, Mapping):
            raise UsageError(f"tolerances={self.tolerances!r}: give a dict of tolerance groups and numbers, e.g. "
                             "{\"pos\": 1e-4}, or None")
        if self.mode is None and self.atol is None and not self.tolerances:
            return None
        try:
            return Tolerances.for_mode(self.mode or DEFAULT_MODE, atol=self.atol, groups=self.tolerances)
        except ValueError as e:
            raise UsageError(str(e)) from None


def rebuild_env(meta: RecordingMeta, *, geometry: str = "auto", imports: Sequence[str] = (),
                recording: str | Path | None = None, trust_recorded_imports: bool = False) -> Any:
    """The recorded env rebuilt for viewing: CPU sim, one sub-scene, state observations, no render mode.

    A render device is used when there is one (for visual meshes and colours) unless `geometry` is
    ``"collision"``, which builds the env without rendering (faster). The task's code is imported first:
    `imports` (``--import``) if given, else the recorded imports with the user's word (`trust_recorded_imports`),
    found also beside `recording` (its path) (`simreel.sim.user_code.resolve_task_imports`).
    """
    from simreel.sim.rebuild import env_from_meta, state_only_kwargs
    from simreel.sim.user_code import resolve_task_imports

    found = resolve_task_imports(meta.imports, explicit=imports, recording=recording, trust=trust_recorded_imports)
    return env_from_meta(
        dataclasses.replace(meta, imports=found),
        num_envs=1,
        sim_backend="physx_cpu",
        obs_mode="state",
        render_backend="none" if geometry == "collision" else "auto",
        env_kwargs=state_only_kwargs(meta),
    )


def check_rrd_target(path: str | Path, *, overwrite: bool, shown: Sequence[str | Path] = (),
                     make_folder: bool = False) -> Path:
    """`UsageError` unless a session can be saved at `path` (``--save``), before any work: a file name ending in
    .rrd; none of the recordings `shown` nor a file kept beside one (`check_distinct`: a recording is known by its
    bytes, whatever its name, so one named .rrd, or a link to one, would be written over); and what `check_output`
    refuses (an existing file without `overwrite`, a missing folder unless `make_folder` makes it). Returns `path`."""
    from simreel.formats import recording_files
    from simreel.io.targets import check_distinct, check_output

    check_flag("overwrite", overwrite)
    if Path(path).suffix.lower() != ".rrd":  # a name, not what Path makes of it: Path("") is "."
        raise UsageError(f"--save {path}: the output must be a file name ending in .rrd, such as run.rrd")
    path = Path(path)
    for recording in shown:
        check_distinct({"--save": [path]}, recording_files(recording), input_label=f"the recording {recording}")
    if make_folder and path.name:
        path.parent.mkdir(parents=True, exist_ok=True)
    return check_output(path, overwrite=overwrite, option="--save")


def viewer_executable() -> str | None:
    """The ``rerun`` viewer installed with the rerun-sdk simreel streams with: beside the running Python (a venv's
    bin/), else on PATH, else None. A ``rerun`` on PATH from another install (another venv, active in the shell) may
    be another Rerun version, whose viewer need not read this one's stream: it comes second."""
    import shutil
    import sys

    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.is_file() else shutil.which("rerun")


_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
"""What an HTTP/2 client sends first: the connection preface and an empty SETTINGS frame."""
_ANSWER_S = 5.0
"""How long what listens on the viewer's port has to answer that preface (a Rerun viewer answers in microseconds)."""


def _grpc_problem(port: int) -> str | None:
    """Why what listens on ``port`` is no gRPC server (None: it answers the HTTP/2 preface with a SETTINGS frame, as
    a Rerun viewer does). Rerun takes anything listening there for an open viewer, and its flush into a listener
    that never answers would wait for ever."""
    import socket

    try:
        with socket.create_connection(("127.0.0.1", port), timeout=_ANSWER_S) as s:
            s.sendall(_HTTP2_PREFACE)
            answer = s.recv(9)
    except TimeoutError:
        return f"it did not answer a gRPC client in {_ANSWER_S:.0f} s"
    except OSError as e:
        return f"it dropped the connection: {e.strerror or e}"
    if not answer:
        return "it closed the connection without answering"
    if len(answer) < 4 or answer[3] != 4:  # byte 3 of a frame header is its type; 4: SETTINGS
        return "it answered, but not as a gRPC server does"
    return None


def _refuse_unless_grpc(port: int) -> None:
    problem = _grpc_problem(port)
    if problem is not None:
        raise _refused(port, problem)


def _viewer_gone(why: str) -> ViewError:
    return ViewError(f"the Rerun viewer did not take the session ({why}): it could not open its window, or it "
                     "closed; use --save OUT.rrd and open it elsewhere, or --serve")


def _refused(port: int, why: str) -> ViewError:
    return ViewError(f"what listens on port {port} refused the session ({why}): it is not a Rerun viewer, or one "
                     "that dropped the connection; use --grpc-port with a free port, or --save OUT.rrd")


def _flush_to_viewer(rec: rr.RecordingStream, port: int, *, wait_s: float = 1.0, host: str = LOCALHOST) -> None:
    """Send everything logged to the viewer on ``port``, giving up once the viewer stops listening or the
    connection fails.

    Rerun's own flush waits forever for a viewer that went away, inside Rust where Ctrl-C and SIGTERM are not
    seen; waiting ``wait_s`` at a time lets signals through and checks the viewer between waits. A slow viewer
    that still listens is waited for; a flush that fails before its time is up is a connection that failed for
    good (another server on the port, a viewer that dropped it) and is not tried again. A flush can also succeed
    into the socket of a viewer that just died, so the viewer must still listen after it for the session to count
    as sent.
    """
    while True:
        started = time.monotonic()
        try:
            rec.flush(timeout_sec=wait_s)
        except RuntimeError as e:
            failed_at_once = time.monotonic() - started < wait_s / 2
            if failed_at_once:
                time.sleep(wait_s / 2)  # a viewer that is closing can still listen for a moment
            if not listening(port, host):
                raise _viewer_gone(first_line(e)) from e
            if failed_at_once:
                raise _refused(port, first_line(e)) from e
            continue
        if not listening(port, host):
            raise _viewer_gone(f"nothing listens on port {port} any more")
        return


def _joint_names(u: Any) -> dict[str, list[str]]:
    out = {}
    for name, art in u.scene.state_dict_registry.articulations.items():
        try:
            names = [j.name for j in art.active_joints]
        except Exception:  # merged views of different parts have no common joints
            names = []
        part = art._objs[0]
        if len(names) != len(part.active_joints):
            names = [j.child_link.entity.name for j in part.active_joints]
        out[name] = names
    return out


def _eye(u: Any) -> tuple[tuple[float, float, float], tuple[float, float, float]] | None:
    """Eye position and look target of the task's human render camera (SAPIEN cameras look along +x)."""
    try:
        cfg = u._default_human_render_camera_configs
        cfg = cfg[0] if isinstance(cfg, (list, tuple)) else cfg
        raw = np.asarray(getattr(cfg.pose, "raw_pose", None).reshape(-1, 7)[0], np.float64)
    except Exception:
        return None
    p, (w, x, y, z) = raw[:3], raw[3:]
    forward = np.array([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])
    target = p + forward * max(float(np.linalg.norm(p)), 0.5)
    return tuple(float(v) for v in p), tuple(float(v) for v in target)  # type: ignore[return-value]


@dataclass
class ViewSession:
    """A prepared session: log it with `save`, `spawn`, `serve` or `log_to`. Close it to free the env."""

    recording: EpisodeRun
    compared: EpisodeRun | None
    """The episode of ``compare`` drawn beside the recording, if any."""
    env: Any
    bodies: list[SceneBody]
    geometry: list[BodyGeometry]
    geometry_source: str
    comparison: ViewComparison | None = None
    explanation: Explanation | None = None
    """Why the compared episode diverged (`simreel.viewers.compare.explain_for_view`), when it did."""
    block_steps: int | None = None
    joint_names: dict[str, list[str]] = field(default_factory=dict)
    eye: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    owns_env: bool = False
    pose_source: str = ""
    """``recorded`` (body poses read from the file) or ``restored`` (states restored into the env), after logging."""
    timings: dict[str, float] = field(default_factory=dict)
    served: Any = field(default=None, repr=False)
    """The servers `serve` started (`simreel.viewers.web_server.WebServer`), until `close`."""

    # ------------------------------------------------------------------ identity and layout
    @property
    def meta(self) -> RecordingMeta:
        return self.recording.meta

    @property
    def episode(self) -> Episode:
        return self.recording.episode

    @property
    def recording_id(self) -> str:
        return f"{self.recording.file_name}#episode-{self.episode.meta.index}"

    @property
    def divergence(self) -> Any:
        """The compared episode's first divergence (`simreel.verdicts.compare.Divergence`), or None."""
        return None if self.comparison is None else self.comparison.divergence

    @property
    def period(self) -> float | None:
        return self.meta.control_period

    def layout(self) -> Layout:
        from simreel.viewers.blueprint import Layout
        from simreel.viewers.log_cameras import camera_streams
        from simreel.viewers.log_contacts import active_channels

        groups = ["reward", "success", "qpos"]
        if any(k not in ("success", "elapsed_steps") for k in self.episode.info):
            groups.append("info")
        forces = self.episode.contact_forces
        if forces is not None and active_channels(forces).any():
            groups.append("contacts")
        focus = None
        if self.divergence is not None:
            s = step_of_row(divergence_row(self.divergence))
            focus = (max(-1, s - 10), min(self.episode.length - 1, s + 10))
        eye, target = self.eye if self.eye is not None else (None, None)
        return Layout(
            compare=self.compared is not None,
            cameras=tuple(camera_streams(self.recording.rows.fields)),
            plot_groups=tuple(groups),
            eye=eye,
            look_target=target,
            focus=focus,
            title=f"{self.meta.env_id} · episode {self.episode.meta.index}",
        )

    def blueprint(self) -> rrb.Blueprint:
        from simreel.viewers.blueprint import session_blueprint

        return session_blueprint(self.layout())

    # ------------------------------------------------------------------ sinks
    def new_stream(self) -> rr.RecordingStream:
        import rerun as rr

        return rr.RecordingStream(APPLICATION_ID, recording_id=self.recording_id)

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Write the session to an .rrd file (with its blueprint) and return the path; its folder is made if missing.

        `path` is checked first (`check_rrd_target`): an existing file is refused without `overwrite`, as every
        simreel output is, and the recordings shown are never written over. The file is written whole or not at all
        (`staged_output`): an existing one is replaced only once the new one is complete, and a file another run
        wrote meanwhile is kept without `overwrite` (`UsageError`); a full disk is a `StorageError`, never a wait.
        """
        shown = [run.path for run in (self.recording, self.compared) if run is not None]
        path = check_rrd_target(path, overwrite=overwrite, shown=shown, make_folder=True)
        with staged_output(path, overwrite=overwrite, option="--save") as partial:
            write_rrd(self.new_stream(), partial, path, self.blueprint(), self.log_to)
        return path

    def spawn(self, *, port: int = 9876) -> None:
        """Open the native Rerun viewer (a separate process) and stream the session to it.

        The viewer is the ``rerun`` executable on PATH, else the one beside this Python (a venv's bin/). A viewer
        that cannot open its window binds its port and exits, and what listens on the port without answering as a
        gRPC server (`_grpc_problem`) is no viewer: both are refused before the stream connects; a viewer that goes
        away while the session streams is reported, not waited on forever (`_flush_to_viewer`).
        """
        import rerun as rr

        rec = self.new_stream()
        if listening(port):  # Rerun would take whatever listens there for an open viewer: refused before it does
            _refuse_unless_grpc(port)
        try:
            rr.spawn(port=port, connect=False, recording=rec, executable_path=viewer_executable())
        except RuntimeError as e:
            raise ViewError(f"could not start the Rerun viewer ({first_line(e)}); use --save OUT.rrd and open it "
                            "elsewhere") from e
        if not listening(port):
            raise _viewer_gone(f"nothing listens on port {port}")
        _refuse_unless_grpc(port)
        rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy", default_blueprint=self.blueprint())
        self.log_to(rec)
        _flush_to_viewer(rec, port)

    def serve(self, *, web_port: int = 9090, grpc_port: int = 9876, bind: str = LOCALHOST,
              memory_limit: str | None = None, open_browser: bool = False) -> str:
        """Serve the session: a gRPC server holding it, and the web viewer (HTML + Wasm) that connects to it, both
        listening on `bind` only (default: this machine; `simreel.viewers.web_server`).

        Returns the web viewer's URL (`web_viewer_url`: the gRPC server to open, the WebGL renderer). Both serve
        until this session is closed (or the process ends). The server keeps everything logged, up to
        `memory_limit` (``2GB``, ``25%``; None: Rerun's default), so viewers that connect later see the whole
        episode. To serve several sessions from one server, start it with `start_web_server` and `stream_to` it.
        """
        import webbrowser

        from simreel.viewers.web_server import start_web_server

        self.served = start_web_server(bind=bind, web_port=web_port, grpc_port=grpc_port, memory_limit=memory_limit)
        url = self.stream_to(self.served)
        if open_browser:
            webbrowser.open(url)
        return url

    def stream_to(self, server: Any) -> str:
        """Send the session, as one Rerun recording, to a running `WebServer` (it stays open when this session is
        closed) and return the web viewer's URL."""
        rec = self.new_stream()
        rec.connect_grpc(server.grpc_url, default_blueprint=self.blueprint())
        self.log_to(rec)
        _flush_to_viewer(rec, server.grpc_port, host=reached_at(server.bind).strip("[]"))
        host = "localhost" if server.bind == LOCALHOST else reached_at(server.bind)
        return web_viewer_url(server.web_port, server.grpc_url, host=host)

    # ------------------------------------------------------------------ logging
    def log_to(self, rec: rr.RecordingStream) -> None:
        """Log the whole session into `rec` (whatever its sink): `simreel.viewers.log_session`."""
        from simreel.viewers.log_session import log_session

        log_session(rec, self)

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Stop serving (`serve`), close the files the session opened and the env if the session built it."""
        self.recording.close()
        if self.compared is not None:
            self.compared.close()
        if self.served is not None:
            self.served.close()
            self.served = None
        if self.owns_env and self.env is not None:
            self.env.close()
            self.env = None

    @contextlib.contextmanager
    def closed_on_error(self) -> Iterator[None]:
        """Close the session when the block raises."""
        try:
            yield
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> ViewSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def build_session(source: Source, options: ViewOptions | None = None, env: Any = None, **overrides: Any) -> ViewSession:
    """Prepare a Rerun session of one episode of the recording `source` (.h5 or .mcap path, or a reader).

    Args:
        options: a `ViewOptions`; keyword arguments override its fields, e.g. ``build_session("run.h5",
            episode=3, compare="replayed.h5")``.
        env: an already built env of the recording's task with ``num_envs=1`` on the CPU sim (e.g. from
            `rebuild_env`); by default one is built from the recording's metadata and closed with the session.

    Raises:
        RecordingFileError: a file is missing, unreadable or has no such episode.
        StateLayoutError: the rebuilt env does not match the recording.
        ViewError: `compare` is of another env or episode.
        EnvBuildError / RenderUnavailableError: the env cannot be rebuilt.
    """
    opts = options_with(ViewOptions, options, overrides, "build_session(path, episode=3)")
    asked = opts.check()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    runs = [read_run(source, opts.episode)]
    try:
        if opts.compare is not None:
            runs.append(read_compare(opts.compare, runs[0]))
        timings["read_s"] = time.perf_counter() - t0
        session = _session(source, env, opts, (runs[0], runs[1] if len(runs) > 1 else None), timings)
    except BaseException:
        for run in runs:
            run.close()
        raise
    rec_run, cmp_run = session.recording, session.compared
    if cmp_run is not None:
        with session.closed_on_error():
            channels = rec_run.meta.contact_channels
            tolerances, judged_with = judging_tolerances(asked, cmp_run.meta, rec_run.meta, _source_path(source))
            session.comparison = compare_for_view(rec_run.rows, cmp_run.rows, channels=channels,
                                                  tolerances=tolerances, rows=opts.block_steps)
            session.comparison.judged_with = judged_with
            session.explanation = explain_for_view(rec_run.episode, cmp_run.episode, session.comparison, channels,
                                                   role=cmp_run.role)
    return session


def _session(source: Source, env: Any, opts: ViewOptions, runs: tuple[EpisodeRun, EpisodeRun | None],
             timings: dict[str, float]) -> ViewSession:
    """The session of `runs` in `env` (None: rebuilt from the recording's metadata, closed on failure)."""
    owns = env is None
    t1 = time.perf_counter()
    if env is None:
        env = rebuild_env(runs[0].meta, geometry=opts.geometry, imports=opts.imports, recording=_source_path(source),
                          trust_recorded_imports=opts.trust_recorded_imports)
    timings["env_s"] = time.perf_counter() - t1
    try:
        return _prepare(env, owns, opts, runs, timings)
    except BaseException:
        if owns:
            env.close()
        raise


def _source_path(source: Source) -> str | Path:
    """The recording's path, however it was given."""
    return source.path if isinstance(source, EpisodeReader) else source


def states_by_stepping(unwrapped: Any, episode: Episode) -> None:
    """Fill the `env_states` of an episode whose file holds none (a ManiSkill file recorded without them) by
    stepping its recorded actions from the reproduced reset in `unwrapped`; the session then draws those.
    `ViewError` for an episode without a seed: its reset cannot be reproduced, so those states would be another's."""
    import torch

    if episode.meta.seed is None or episode.meta.seed_unchecked:  # (an unchecked seed may be stale)
        raise ViewError(f"episode {episode.meta.index}: {UNSEEDED_WITHOUT_STATES}: its poses cannot be shown")

    rows = [read_state(unwrapped)]
    for action in episode.actions:
        unwrapped.step(torch.from_numpy(np.ascontiguousarray(action))[None])
        rows.append(read_state(unwrapped))
    episode.env_states = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    episode.meta.notes.append("the file holds no states: the poses shown come from stepping its recorded actions")


def _prepare(env: Any, owns: bool, opts: ViewOptions, runs: tuple[EpisodeRun, EpisodeRun | None],
             timings: dict[str, float]) -> ViewSession:
    """Reset `env` to the recorded episode's scene and read its bodies and geometry."""
    rec_run, cmp_run = runs
    u = env.unwrapped
    if int(u.num_envs) != 1 or u.scene.gpu_sim_enabled:
        raise UsageError("build_session(env=...) needs an env with num_envs=1 on the CPU sim (see rebuild_env)")
    t2 = time.perf_counter()
    # the episode's scene (heterogeneous tasks draw their objects when they build it); a caller's env: unknown
    reset_to_episode(env, rec_run.episode.meta, scene_seed=GYM_MAKE_SEED if owns else None)
    if rec_run.meta.state_layout:
        check_rebuilt_layout(u, rec_run.meta.env_id, rec_run.meta.state_layout)
    else:
        states_by_stepping(u, rec_run.episode)
    bodies = scene_bodies(u)
    used, geo = scene_geometry(u, bodies, source=opts.geometry)
    timings["scene_s"] = time.perf_counter() - t2
    return ViewSession(recording=rec_run, compared=cmp_run, env=env, bodies=bodies, geometry=geo,
                       geometry_source=used, block_steps=opts.block_steps,
                       joint_names=_joint_names(u), eye=_eye(u), owns_env=owns, timings=timings)
