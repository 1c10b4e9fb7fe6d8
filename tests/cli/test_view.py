"""`simreel view`: saving a session, the default output, --compare, --spawn, --serve, and recordings it cannot show."""

from __future__ import annotations

import os
import shlex
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import parse_qs, urlparse
from urllib.request import urlopen

import pytest
from support.processes import (
    DISPLAY_VARS,
    answering_display,
    free_port,
    free_ports,
    read_line,
    reap,
    simreel_command,
    stop_child,
    without_display,
)
from support.rrd import read_served, running_grpc_server
from support.viewer_data import STEPS

from simreel.cli.main import main


def test_view_save(pickcube_h5, tmp_path, capsys, rrd_reader):
    out = tmp_path / "pc.rrd"
    assert main(["view", str(pickcube_h5), "--save", str(out), "--geometry", "collision", "--episode", "0"]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    rrd = rrd_reader(out)
    assert "/world/cube" in rrd.data and rrd.blueprint_views


def test_view_defaults_to_saving_without_a_display(pickcube_h5, tmp_path, monkeypatch, capsys):
    """No window can open: the session is saved, and the hint serves it to a browser (the `rerun` viewer itself
    fails there with a winit EventLoopError); tests/viewers/test_web_server.py opens what it prints."""
    from simreel.cli.view import viewer_command

    for name in DISPLAY_VARS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    assert main(["view", str(pickcube_h5), "--geometry", "collision"]) == 0
    out = tmp_path / "pickcube.episode0.rrd"
    assert out.is_file()
    assert capsys.readouterr().out.splitlines()[-3:] == [
        f"no display here; serve it to a browser with: {viewer_command()} --serve-web {out} --bind 127.0.0.1 "
        "--web-viewer-port 9090 --port 9876 --renderer webgl",
        "then open: http://localhost:9090/?url=rerun%2Bhttp://127.0.0.1:9876/proxy&renderer=webgl",
        "from another machine: ssh -L 9090:localhost:9090 -L 9876:localhost:9876 USER@THIS-HOST, then open the URL "
        "there"]


def test_with_a_display_the_hint_opens_the_viewer(tmp_path, monkeypatch):
    from simreel.cli.view import open_command, open_hint

    out = tmp_path / "pc.rrd"
    with answering_display() as env:
        monkeypatch.setenv("DISPLAY", env["DISPLAY"])
        assert open_hint(out) == [f"open it with: {open_command(out)}"]


VENV_BIN = Path(sys.executable).parent
"""The venv's bin/: simreel, python and rerun, as `make setup` installs them."""


def _runs_here(command: str, cwd: Path, path_variable: str) -> str:
    """Run the viewer of an `open it with:` command with --version, in the shell the hint was printed for."""
    viewer, _ = shlex.split(command)
    done = subprocess.run(["bash", "-c", f"{shlex.quote(viewer)} --version"], cwd=cwd, capture_output=True,
                          text=True, env={**os.environ, "PATH": path_variable}, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.parametrize("where", ["activated", "venv-parent", "elsewhere", "another rerun on PATH"])
def test_the_open_hint_works_in_the_shell_it_is_printed_in(tmp_path, monkeypatch, where):
    """`rerun FILE` only where `rerun` on PATH is simreel's viewer (an activated venv); otherwise the viewer's
    path, relative where it lies below the current folder (`.venv/bin/rerun` in the repository root) — also where
    another install's `rerun` comes first on PATH (another venv active in the shell: maybe another Rerun)."""
    from simreel.cli.view import open_command

    bare_path = os.pathsep.join(p for p in os.environ["PATH"].split(os.pathsep) if Path(p) != VENV_BIN)
    other = tmp_path / "other-venv-bin"
    other.mkdir()
    (other / "rerun").write_text("#!/bin/sh\necho another rerun\n")
    (other / "rerun").chmod(0o755)
    path_variable = {"activated": f"{VENV_BIN}{os.pathsep}{bare_path}",
                     "another rerun on PATH": f"{other}{os.pathsep}{bare_path}"}.get(where, bare_path)
    cwd = VENV_BIN.parents[1] if where == "venv-parent" else tmp_path
    monkeypatch.setenv("PATH", path_variable)
    monkeypatch.chdir(cwd)
    command = open_command(tmp_path / "my session.rrd")
    expected = {"activated": "rerun", "venv-parent": os.path.relpath(VENV_BIN / "rerun", cwd)}.get(
        where, str(VENV_BIN / "rerun"))
    assert command == f"{expected} '{tmp_path}/my session.rrd'"
    assert _runs_here(command, cwd, path_variable).startswith("rerun-cli 0.41.0")


def test_make_demo_prints_one_hint_that_works(pickcube_h5, tmp_path):
    """What `make demo` runs on a machine without a display: the venv's simreel from the repository root, the venv
    not activated. The hint is the last three lines (serve, open, ssh), and its viewer runs in that shell (before,
    it said `rerun ...`: not on that PATH; then `rerun FILE`, which fails without a display)."""
    repo = VENV_BIN.parents[1]
    bare_path = os.pathsep.join(p for p in os.environ["PATH"].split(os.pathsep) if Path(p) != VENV_BIN)
    out = tmp_path / "pickcube.rrd"
    done = subprocess.run([os.path.relpath(VENV_BIN / "simreel", repo), "view", str(pickcube_h5), "--geometry",
                           "collision", "--save", str(out)], cwd=repo, env={**without_display(), "PATH": bare_path},
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert [line for line in lines if "rerun" in line] == lines[-3:-1]  # the command to serve, its URL; then ssh
    serve = lines[-3].split("serve it to a browser with: ")[1]
    assert serve.startswith(f"{os.path.relpath(VENV_BIN / 'rerun', repo)} --serve-web {out} ")
    _runs_here(f"{serve.split()[0]} x", repo, bare_path)
    makefile = (repo / "Makefile").read_text()
    assert "rerun" not in makefile.split("\ndemo:")[1].split("\n\n")[0]  # the demo target prints no hint of its own


def test_compare_with_another_env_is_refused(pickcube_h5, tmp_path, capsys):
    import dataclasses

    from simreel.formats import open_reader, open_writer

    with open_reader(pickcube_h5) as r:
        meta, ep = dataclasses.replace(r.meta, env_id="PushCube-v1"), r.read_episode(0)
    other = tmp_path / "other.h5"
    with open_writer(other, meta) as w:
        w.write_episode(ep)
    assert main(["view", str(pickcube_h5), "--compare", str(other), "--geometry", "collision"]) == 2
    assert "it is a recording of PushCube-v1, not of PickCube-v1" in capsys.readouterr().err


def test_view_mcap_recording(pickcube_h5, tmp_path, rrd_reader):
    from simreel.formats import open_reader, open_writer

    mcap = tmp_path / "pickcube.mcap"
    with open_reader(pickcube_h5) as r, open_writer(mcap, r.meta) as w:
        w.write_episode(r.read_episode(0))
    out = tmp_path / "mcap.rrd"
    assert main(["view", str(mcap), "--save", str(out), "--geometry", "collision"]) == 0
    rrd = rrd_reader(out)
    assert rrd.recording_ids == ["pickcube.mcap#episode-0"]
    assert rrd.steps("/world/cube", "Transform3D:translation") == list(range(-1, 30))


def _no_env(*args, **kwargs):
    raise AssertionError("the env was built before the output was checked")


def test_view_refuses_to_overwrite_an_rrd(pickcube_h5, tmp_path, monkeypatch, capsys):
    import simreel.viewers.session as session

    out = tmp_path / "kept.rrd"
    out.write_bytes(b"an earlier session")
    with monkeypatch.context() as m:
        m.setattr(session, "rebuild_env", _no_env)  # refused before any work
        assert main(["view", str(pickcube_h5), "--save", str(out), "--geometry", "collision"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out} already exists; pass --overwrite to replace it" in err
    assert out.read_bytes() == b"an earlier session"
    assert main(["view", str(pickcube_h5), "--save", str(out), "--geometry", "collision", "--overwrite"]) == 0
    assert out.stat().st_size > 1000


def test_view_refuses_to_overwrite_its_default_output(pickcube_h5, tmp_path, monkeypatch, capsys):
    import simreel.viewers.session as session

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "pickcube.episode0.rrd").write_bytes(b"x")
    monkeypatch.setattr(session, "rebuild_env", _no_env)
    assert main(["view", str(pickcube_h5), "--geometry", "collision"]) == 2
    assert "pickcube.episode0.rrd already exists; pass --overwrite" in capsys.readouterr().err


@pytest.mark.parametrize(
    "save_and_message",
    [
        ("{tmp}", "that is a folder"),
        ("{rec}/out.rrd", "is not a folder"),  # a folder that cannot be made: the recording is a file
    ],
)
def test_view_checks_the_output_folder_before_building_the_env(pickcube_h5, tmp_path, monkeypatch, capsys,
                                                               save_and_message):
    import simreel.viewers.session as session

    monkeypatch.setattr(session, "rebuild_env", _no_env)
    save, message = save_and_message
    save = save.format(tmp=tmp_path / "dir.rrd", rec=pickcube_h5)
    (tmp_path / "dir.rrd").mkdir()
    assert main(["view", str(pickcube_h5), "--save", save, "--geometry", "collision"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_view_tolerances_parse_like_replay(pickcube_h5, capsys):
    with pytest.raises(SystemExit) as e:
        main(["view", str(pickcube_h5), "--tol", "flag=1"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected GROUP=NUMBER with GROUP one of pos, quat" in err


def test_a_recording_of_another_layout_names_each_leaf(pickcube_h5, tmp_path, capsys):
    import dataclasses

    from simreel.formats import open_reader, open_writer

    with open_reader(pickcube_h5) as r:
        meta, ep = dataclasses.replace(r.meta, env_id="PushCube-v1", pose_bodies=[]), r.read_episode(0)
    other = tmp_path / "mislabelled.h5"
    with open_writer(other, meta) as w:
        w.write_episode(dataclasses.replace(ep, body_poses=None))
    assert main(["view", str(other), "--geometry", "collision", "--save", str(tmp_path / "o.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the rebuilt PushCube-v1 has another state layout than the recording" in err
    assert "actors/goal_site: recorded (13,) float32, rebuilt absent" in err


def test_a_gpu_recording_is_viewed_on_the_cpu_sim(pickcube_h5, tmp_path):
    """The viewer always rebuilds on physx_cpu: a recording made on the GPU sim needs no CUDA device to view."""
    import dataclasses

    from simreel.formats import open_reader, open_writer

    with open_reader(pickcube_h5) as r:
        meta, ep = dataclasses.replace(r.meta, sim_backend="physx_cuda"), r.read_episode(0)
    gpu = tmp_path / "gpu.h5"
    with open_writer(gpu, meta) as w:
        w.write_episode(ep)
    assert main(["view", str(gpu), "--geometry", "collision", "--save", str(tmp_path / "gpu.rrd")]) == 0


def test_spawn_without_a_display_is_bad_input_at_once(pickcube_h5, tmp_path):
    """What a shell sees: one line saying there is no display and what to use instead, exit 2, in about the
    time Python takes to start (before, the viewer failed to open and an 'internal error' came ~20 s later)."""
    started = time.perf_counter()
    done = subprocess.run(simreel_command("view", str(pickcube_h5), "--spawn"), env=without_display(),
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    seconds = time.perf_counter() - started
    assert done.returncode == 2, done.stderr
    [line] = done.stderr.splitlines()
    assert line.startswith("simreel view: error: --spawn opens the Rerun viewer in a window, and there is no "
                           "display here (DISPLAY and WAYLAND_DISPLAY are unset)")
    assert "--save OUT.rrd" in line and "--serve" in line
    assert seconds < 10 and not list(tmp_path.iterdir())


def test_spawn_without_a_display_builds_no_env(pickcube_h5, monkeypatch, capsys):
    import simreel.viewers.session as session

    for name in DISPLAY_VARS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(session, "rebuild_env", _no_env)
    assert main(["view", str(pickcube_h5), "--spawn"]) == 2
    assert "there is no display here" in capsys.readouterr().err


def test_a_display_nothing_serves_is_refused_before_the_viewer_starts(pickcube_h5, tmp_path):
    """DISPLAY is set but no X server answers there: a viewer spawned onto it would bind its port and exit, seen
    only after a race with the stream (Rerun then printed its own flush errors). simreel probes the display first:
    one line, exit 2, no viewer started, nothing written."""
    display = f":{free_port()}"  # a display number no X server has
    started = time.perf_counter()
    done = subprocess.run(simreel_command("view", str(pickcube_h5), "--spawn", "--geometry", "collision",
                                          "--grpc-port", str(free_port())),
                          env={**without_display(), "DISPLAY": display}, cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    [line] = done.stderr.splitlines()
    assert line.startswith(f"simreel view: error: --spawn opens the Rerun viewer in a window, and no display server "
                           f"answers at DISPLAY={display}; write the session with --save OUT.rrd")
    assert time.perf_counter() - started < 10 and not list(tmp_path.iterdir())


def test_the_display_probe_asks_the_server(monkeypatch):
    """A display counts only where something accepts connections: X11 by TCP (host:N, port 6000+N) or Unix socket
    (:N), Wayland by its socket."""
    from simreel.cli.view import display_problem, has_display

    for name in DISPLAY_VARS:
        monkeypatch.delenv(name, raising=False)
    assert display_problem() == "there is no display here (DISPLAY and WAYLAND_DISPLAY are unset)"
    with answering_display() as env:
        monkeypatch.setenv("DISPLAY", env["DISPLAY"])
        assert has_display()
    assert not has_display()  # the same display once nothing listens there
    monkeypatch.setenv("DISPLAY", f":{free_port()}")
    assert display_problem() == f"no display server answers at DISPLAY={os.environ['DISPLAY']}"


def test_spawn_sends_the_episode_to_the_viewer_listening_on_its_port(pickcube_h5, tmp_path):
    """A viewer already listens on the port (as one left open does; here `rerun --serve-grpc`, a viewer without
    its window): `--spawn` sends it the whole episode, says so and exits 0."""
    port = free_port()
    with running_grpc_server(port, tmp_path / "server.log") as url, answering_display() as env:
        done = subprocess.run(simreel_command("view", str(pickcube_h5), "--spawn", "--geometry", "collision",
                                              "--grpc-port", str(port)),
                              env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        assert done.stdout.splitlines()[0] == "sent pickcube.h5#episode-0 to the Rerun viewer"
        served = read_served(url, tmp_path / "served",
                             lambda c: c.steps("/world/cube", "Transform3D:translation") == list(range(-1, STEPS)))
    assert served.recording_ids == ["pickcube.h5#episode-0"] and served.blueprint_views


def test_a_viewer_that_goes_away_is_reported_not_waited_for(tmp_path):
    """The viewer ends after the stream connected: flushing to it fails within seconds with the one-line
    error, where Rerun's own flush waits forever or, into the dead viewer's socket, reports success."""
    import rerun as rr

    from simreel.errors import ViewError
    from simreel.viewers.session import _flush_to_viewer

    port = free_port()
    rec = rr.RecordingStream("simreel-test")
    with running_grpc_server(port, tmp_path / "server.log") as url:
        rec.connect_grpc(url)
        rec.log("points", rr.Points3D([[0.0, 0.0, 0.0]]))
        _flush_to_viewer(rec, port)  # delivered while it listens
    rec.log("points", rr.Points3D([[1.0, 0.0, 0.0]]))
    started = time.perf_counter()
    with pytest.raises(ViewError, match="the Rerun viewer did not take the session"):
        _flush_to_viewer(rec, port)
    assert time.perf_counter() - started < 30


def test_a_port_held_by_another_server_is_reported_not_waited_on(pickcube_h5, tmp_path):
    """Something that is not a Rerun viewer (an HTTP server) listens on the port: Rerun takes it for an open
    viewer and its gRPC stream fails at once, for good. One line naming the port and what to do, exit 2; before,
    simreel retried in a tight loop while the port listened, until the machine ran out of ephemeral ports and
    that was taken for a viewer that had closed."""
    import http.server
    import threading

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    port = server.server_address[1]
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        with answering_display() as env:
            done = subprocess.run(simreel_command("view", str(pickcube_h5), "--spawn", "--geometry", "collision",
                                                  "--grpc-port", str(port)),
                                  env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    finally:
        server.shutdown()
        server.server_close()
    assert done.returncode == 2, done.stderr
    ours = [line for line in done.stderr.splitlines() if line.startswith("simreel view:")]
    assert len(ours) == 1 and ours[0].startswith(f"simreel view: error: what listens on port {port} refused the "
                                                 "session ("), done.stderr
    assert "--grpc-port" in ours[0]


def test_a_port_held_by_a_silent_listener_is_reported_not_waited_on(pickcube_h5, tmp_path):
    """Something listens on the port and never answers (a stuck process, a proxy): Rerun took it for an open viewer
    and its flush waited for ever. One line naming the port, exit 2, within seconds."""
    import socket

    with socket.socket() as silent, answering_display() as env:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        port = silent.getsockname()[1]
        started = time.perf_counter()
        done = subprocess.run(simreel_command("view", str(pickcube_h5), "--spawn", "--geometry", "collision",
                                              "--grpc-port", str(port)),
                              env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == [f"simreel view: error: what listens on port {port} refused the session (it "
                                        "did not answer a gRPC client in 5 s): it is not a Rerun viewer, or one that "
                                        "dropped the connection; use --grpc-port with a free port, or --save OUT.rrd"]
    assert time.perf_counter() - started < 60


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_serve_serves_the_episode_until_stopped(pickcube_h5, tmp_path, rrd_reader, stop):
    """A real `simreel view --serve` on free ports: the page loads, the gRPC server named in the printed URL
    serves the whole episode (read back with `rerun download`, the same data `--save` writes) until Ctrl-C or
    SIGTERM, which end it with exit 0 and free both ports."""
    web, grpc = free_ports(2)
    child = subprocess.Popen(simreel_command("view", str(pickcube_h5), "--serve", "--geometry", "collision",
                                             "--web-port", str(web), "--grpc-port", str(grpc)),
                             cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = read_line(child, timeout=240)
        assert line.startswith(f"serving pickcube.h5#episode-0 at http://localhost:{web}/?url=rerun%2Bhttp://")
        assert line.endswith(" (Ctrl-C to stop)")
        [grpc_url] = parse_qs(urlparse(line.split(" at ")[1].split(" ")[0]).query)["url"]
        assert grpc_url == f"rerun+http://127.0.0.1:{grpc}/proxy"
        with urlopen(f"http://localhost:{web}/", timeout=30) as page:
            assert page.status == 200 and b"web viewer" in page.read()
        served = read_served(grpc_url, tmp_path / "served",
                             lambda c: c.steps("/world/cube", "Transform3D:translation") == list(range(-1, STEPS)))
        assert child.poll() is None  # still serving
        assert _listening_on(web) == _listening_on(grpc) == ["127.0.0.1"]  # not every interface: this machine only
        out, err = stop_child(child, stop)
    finally:
        reap(child)
    assert child.returncode == 0, err
    assert out.splitlines() == [f"ports: web viewer {web}, gRPC {grpc}, on 127.0.0.1",
                                f"from another machine: ssh -L {web}:localhost:{web} -L {grpc}:localhost:{grpc} "
                                "USER@THIS-HOST, then open the URL there",
                                f"stopped serving ({'Ctrl-C' if stop == signal.SIGINT else 'SIGTERM'})"]
    saved = tmp_path / "saved.rrd"
    assert main(["view", str(pickcube_h5), "--geometry", "collision", "--save", str(saved)]) == 0
    expected = rrd_reader(saved)
    assert served.recording_ids == expected.recording_ids == ["pickcube.h5#episode-0"]
    assert served.data == expected.data
    assert sorted(served.blueprint_views) == sorted(expected.blueprint_views)
    for port in (web, grpc):  # nothing listens any more
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", port)) != 0


@pytest.mark.parametrize("option", ["--web-port", "--grpc-port"])
def test_serve_on_a_taken_port_is_refused_before_building_the_env(pickcube_h5, monkeypatch, capsys, option):
    """Rerun reports a taken gRPC port only in its log and then serves nothing; simreel checks both first."""
    import simreel.viewers.session as session

    monkeypatch.setattr(session, "rebuild_env", _no_env)
    with socket.socket() as taken:
        taken.bind(("0.0.0.0", 0))
        taken.listen()
        port = taken.getsockname()[1]
        other = "--grpc-port" if option == "--web-port" else "--web-port"
        assert main(["view", str(pickcube_h5), "--serve", option, str(port), other, str(free_port())]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{option} {port}: the port is taken" in err and f"{option} N" in err


def _listening_on(port: int) -> list[str]:
    """The addresses TCP sockets listen on `port` at, as Linux lists them (/proc/net/tcp, tcp6)."""
    import ipaddress

    found = []
    for table, size in (("/proc/net/tcp", 4), ("/proc/net/tcp6", 16)):
        for line in Path(table).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            address, _, hex_port = local.partition(":")
            if state == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
                raw = bytes.fromhex(address)
                words = b"".join(raw[i:i + 4][::-1] for i in range(0, size, 4))  # each 32-bit word in host order
                found.append(str(ipaddress.ip_address(words)))
    return found


@pytest.mark.parametrize(("args", "said"), [
    (["--serve", "--bind", "10.255.255.254"], "--bind 10.255.255.254: not an address this machine can listen on"),
    (["--serve", "--bind", "localhost:80"], "--bind localhost:80: not an address this machine can listen on"),
    (["--save", "x.rrd", "--bind", "0.0.0.0"], "--bind 0.0.0.0: the address --serve listens on; with --save it would "
                                               "be ignored, so leave it out"),
], ids=["no-interface", "not-an-address", "with-save"])
def test_a_bind_address_that_cannot_work_is_one_line(pickcube_h5, monkeypatch, capsys, args, said):
    import simreel.viewers.session as session

    monkeypatch.setattr(session, "rebuild_env", _no_env)
    tmp_path = Path(tempfile.mkdtemp())
    monkeypatch.chdir(tmp_path)
    assert main(["view", str(pickcube_h5), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"simreel view: error: {said}"), err
    assert list(tmp_path.iterdir()) == []


def _write_replay(src, dst, *, index=0, steps=None):
    """Episode 0 of `src` written to `dst` as episode `index`, cut to its first `steps` when given: a replay file
    that holds another episode, or a replay that ended early."""
    import dataclasses

    from simreel.formats import open_reader, open_writer

    with open_reader(src) as r, open_writer(dst, r.meta) as w:
        ep = r.read_episode(0)
        ep = ep.first_steps(steps) if steps is not None else ep
        w.write_episode(dataclasses.replace(ep, meta=dataclasses.replace(ep.meta, index=index)))
    return dst


def test_compare_never_pairs_an_episode_with_another_episodes_replay(pickcube_h5, tmp_path, capsys):
    """A file holding only episode 1's replay: episode 0 is refused, naming the episode the file has."""
    other = _write_replay(pickcube_h5, tmp_path / "replayed.h5", index=1)
    assert main(["view", str(pickcube_h5), "--compare", str(other), "--save", str(tmp_path / "c.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no episode 0 to compare with episode 0 of pickcube.h5 (it has 1)" in err, err
    assert "pick an episode it has with --episode" in err and not (tmp_path / "c.rrd").exists()


@pytest.mark.parametrize(("steps", "verdict"), [
    (20, f"cut.h5 incomplete: exact for the first 20 of {STEPS} steps; steps 20 to {STEPS - 1} were not checked"),
    (0, f"cut.h5 incomplete: exact at the reset, none of the {STEPS} steps compared"),
], ids=["20-steps", "no-step"])
def test_a_shorter_replay_is_incomplete_never_exact(pickcube_h5, tmp_path, capsys, steps, verdict):
    cut = _write_replay(pickcube_h5, tmp_path / "cut.h5", steps=steps)
    out = tmp_path / "cut.rrd"
    assert main(["view", str(pickcube_h5), "--compare", str(cut), "--save", str(out), "--geometry", "collision"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert verdict in lines and not any("exact: no value" in line for line in lines), lines


def test_view_and_video_judge_a_step_mode_replay_with_the_tolerances_that_judged_it(record, tmp_path, capsys):
    """`replay -o` keeps the tolerances that judged each episode (its provenance), and `view --compare` and `video
    --compare` judge the replay with them when told no others, and say which: a cube moved by 0.1 mm in one recorded
    state is within `--mode step --tol pos=0.01`'s tolerances, as replay said, where actions' (the default for any
    other file) call it diverged. The replay is known as this recording's by its id: also once the recording is moved,
    never of another recording at the same path."""
    import dataclasses
    import json
    import shutil

    from simreel.formats import open_reader, open_writer
    from simreel.model.components import Tolerances
    from simreel.viewers.compare import judging_tolerances

    moved = tmp_path / "moved.h5"
    with open_reader(record("PickCube-v1", 1, 10)) as r, open_writer(moved, r.meta) as w:
        episode = r.read_episode(0)
        episode.env_states["actors/cube"] = episode.env_states["actors/cube"].copy()
        episode.env_states["actors/cube"][5, 0] += 1e-4
        w.write_episode(episode)
    replayed, report = tmp_path / "replayed.h5", tmp_path / "report.json"
    assert main(["replay", str(moved), "--mode", "step", "--tol", "pos=0.01", "-o", str(replayed), "--report",
                 str(report), "-q"]) == 0
    assert json.loads(report.read_text())["episodes"][0]["verdict"] == "within_tolerance"
    capsys.readouterr()
    assert main(["inspect", str(replayed)]) == 0
    assert (f"made by    replay of {moved.resolve()} (simreel replay --mode step; pos 0.01 instead of its defaults), "
            "each episode's verdict kept") in capsys.readouterr().out

    view = ["view", str(moved), "--compare", str(replayed), "--geometry", "collision", "--overwrite"]
    assert main([*view, "--save", str(tmp_path / "stored.rrd")]) == 0
    out = capsys.readouterr().out
    assert ("note: judged with the tolerances `simreel replay --mode step` judged it with when it wrote it (pos 0.01 "
            "instead of its defaults)") in out
    assert "replay within tolerance: no value leaves its tolerance" in out
    assert main([*view, "--save", str(tmp_path / "actions.rrd"), "--mode", "actions"]) == 0
    out = capsys.readouterr().out
    assert "judged with" not in out and "replay diverges" in out and "env_states/actors/cube[p]" in out

    video = ["video", str(moved), "--compare", str(replayed), "-o", str(tmp_path), "--overwrite", "-q"]
    assert main(video) == 0
    out = capsys.readouterr().out
    assert "replay within tolerance" in out and "note: judged with the tolerances `simreel replay --mode step`" in out
    assert main([*video, "--mode", "actions"]) == 0
    assert "replay diverged" in capsys.readouterr().out

    with open_reader(moved) as r, open_reader(replayed) as o:
        recording, made = r.meta, o.meta
    stored = made.provenance["tolerances"]
    elsewhere = shutil.copy(moved, tmp_path / "elsewhere.h5")  # a copy keeps the recording's id
    assert judging_tolerances(None, made, recording, elsewhere)[0].to_json() == stored
    another = dataclasses.replace(recording, recording_id="another")  # a new recording at the same path
    tolerances, note = judging_tolerances(None, made, another, moved)
    assert tolerances.to_json() == Tolerances.for_mode("actions").to_json()
    assert note == (f"the compared file is a replay of another recording ({moved.resolve()}): judged with the default "
                    "tolerances (--mode actions)")
    as_actions = dataclasses.replace(made, provenance={**made.provenance, "mode": "actions",
                                                       "tolerances": Tolerances.for_mode("actions").to_json()})
    assert judging_tolerances(None, as_actions, recording, moved)[1] == ""  # the defaults: nothing to say
