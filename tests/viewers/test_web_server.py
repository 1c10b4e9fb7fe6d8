"""Viewing in a browser on a machine without a display or a GPU: `simreel view --serve` and the printed
`rerun --serve-web` of a saved .rrd, each opened at the URL simreel prints in headless Chromium (software
rendering), with a screenshot that must show the 3D scene: the robot and the red cube drawn, not Rerun's loading
screen or its WebGPU crash page."""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess

import numpy as np
import pytest
from support.browser import chromium_missing, distinct_colours, pixels, screenshot
from support.processes import free_ports, read_line, reap, simreel_command, stop_child, without_display

from simreel.cli.main import main

pytestmark = pytest.mark.skipif(chromium_missing() is not None, reason=chromium_missing() or "")

SCENE_BOX = (0.0, 0.1, 0.58, 0.75)
"""Where Rerun's layout draws the 3D view, in fractions of the page (left, top, right, bottom)."""


def _scene(png: bytes) -> np.ndarray:
    image = pixels(png).astype(int)
    height, width = image.shape[:2]
    return image[int(SCENE_BOX[1] * height):int(SCENE_BOX[3] * height), :int(SCENE_BOX[2] * width)]


def _cube_pixels(png: bytes) -> int:
    """PickCube's cube is red."""
    area = _scene(png)
    return int(((area[..., 0] > 180) & (area[..., 1] < 90) & (area[..., 2] < 90)).sum())


def _robot_pixels(png: bytes) -> int:
    """The Panda's collision shapes are light grey, its visual meshes white with black: grey or dark, not tinted."""
    area = _scene(png)
    spread = area.max(axis=-1) - area.min(axis=-1)
    return int(((spread < 16) & (area.max(axis=-1) < 235)).sum())


def _scene_drawn(png: bytes) -> bool:
    return _cube_pixels(png) >= 30 and distinct_colours(png, box=SCENE_BOX) >= 40


def _check_scene(png: bytes, tmp_path, name: str) -> None:
    (tmp_path / name).write_bytes(png)
    assert _scene_drawn(png), f"no 3D scene in the screenshot {tmp_path / name}"
    assert _robot_pixels(png) > 0.01 * _scene(png)[..., 0].size, f"no robot in {tmp_path / name}"


def test_serve_is_seen_in_a_software_rendered_browser(pickcube_h5, tmp_path):
    """`simreel view --serve` of two files: the printed URL (WebGL renderer) shows the scene; the ports and the
    ssh line are printed; Ctrl-C ends it with exit 0."""
    second = tmp_path / "second.h5"
    shutil.copyfile(pickcube_h5, second)
    web, grpc = free_ports(2)
    child = subprocess.Popen(simreel_command("view", str(pickcube_h5), str(second), "--serve",
                                             "--geometry", "collision", "--web-port", str(web), "--grpc-port",
                                             str(grpc), "--server-memory-limit", "1GB"),
                             cwd=tmp_path, env=without_display(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        line = read_line(child, timeout=240)
        assert line.startswith("serving pickcube.h5#episode-0, second.h5#episode-0 at http://localhost:")
        url = line.split(" at ")[1].split(" ")[0]
        assert url.endswith("&renderer=webgl")
        png = screenshot(url, _scene_drawn, timeout_s=40, settle_s=4)
        out, err = stop_child(child, signal.SIGINT)
    finally:
        reap(child)
    assert child.returncode == 0, err
    assert out.splitlines() == [
        "2 recordings: pick one in the viewer's recordings panel (top left)",
        f"ports: web viewer {web}, gRPC {grpc}, on 127.0.0.1",
        f"from another machine: ssh -L {web}:localhost:{web} -L {grpc}:localhost:{grpc} USER@THIS-HOST, then open "
        "the URL there",
        "stopped serving (Ctrl-C)"]
    _check_scene(png, tmp_path, "served.png")


def test_the_printed_serve_web_command_of_a_saved_rrd_is_seen_in_a_browser(pickcube_h5, tmp_path, monkeypatch,
                                                                          capsys):
    """Without a display, `view --save` prints how to serve the file to a browser: that command (on free ports)
    serves it, and the printed URL shows the scene."""
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    out = tmp_path / "pc.rrd"
    assert main(["view", str(pickcube_h5), "--geometry", "collision", "--save", str(out)]) == 0
    serve_line, open_line, ssh_line = capsys.readouterr().out.splitlines()[-3:]
    assert ssh_line.startswith("from another machine: ssh -L 9090:localhost:9090 -L 9876:localhost:9876 ")
    web, grpc = free_ports(2)
    command = serve_line.split("serve it to a browser with: ")[1]
    command = command.replace("--web-viewer-port 9090", f"--web-viewer-port {web}").replace("--port 9876",
                                                                                           f"--port {grpc}")
    url = open_line.removeprefix("then open: ").replace(":9090/", f":{web}/").replace(":9876/", f":{grpc}/")
    server = subprocess.Popen(shlex.split(command), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    try:
        png = screenshot(url, _scene_drawn, timeout_s=40, settle_s=3)
    finally:  # the whole group: the `rerun` script runs the viewer binary as a child of its own
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
    _check_scene(png, tmp_path, "saved.png")
